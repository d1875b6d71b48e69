"""
Where each PSM's tool really is: a camera-to-arm registration from the endoscope's images.

Why a registration. A physical dVRK's tool tips are off by millimetres: Hwang et al. (RA-L
2020) measure 2.96 mm mean before correction, and the dVRK's own ECM-PSM registration
(jhu-dvrk/dvrk_camera_registration) leaves the PSMs in "a 5 mm to 10 mm cube" in the camera's
view. A grasp closes on a 1 mm wire with about 2 mm to spare, so each arm's error has to be
known before its first grasp; the held needle (believed against seen) tells an arm's error only
once it holds it. A dVRK lab does what dvrk_camera_registration and Hwang et al. do: move each
PSM to a few poses in the endoscope's view, see the tool, fit a correction. Here:

- **Poses.** Each PSM goes to six poses a centimetre or two above the phantom (around the
  markers the camera sees), wrist straight and jaw closed, so the instrument is a straight
  stick: a dark shaft ending in the bright wrist and jaws; then to two of them again from
  other directions, and at the last one bends its wrist each way and straightens it before a
  look (the same reported pose, the cables' slack taken up the other way).
- **Seen.** In both images, the shaft's axis and the distal end
  (:func:`suture_lfd.perception.instrument.find_instrument`).
- **Model.** The dVRK's error sources, as the robot's kinematics see them: offsets on the first
  three joints (the potentiometer/encoder homing of yaw, pitch and insertion) and a translation
  of the arm's base in the camera's ``world`` (what a registration leaves). Six numbers per arm,
  fitted (:func:`scipy.optimize.least_squares`, soft-L1 loss) to the image residuals of the
  model's projected shaft axis and jaw tips over the six poses -- a bundle adjustment of the
  instrument, needing no depth and no fiducial. Where a robot has other error sources (a base
  rotation, link lengths) the same fit takes more parameters. Given the joints the arm
  reported on its way to each pose, it also fits the dead bands of the cable-driven joints
  (outer yaw, pitch, insertion, wrist pitch and yaw): their play at each pose follows from the
  motion (:mod:`suture_lfd.skill.hysteresis`). The wrist's own offsets (the instrument's roll
  and wrist pitch), seen too weakly here (a straight closed jaw), are fitted later from the held
  needle, a 10 mm lever (:meth:`ArmCorrection.with_wrist_offset`;
  :meth:`suture_lfd.skill.perceived.PerceivedScene.look_at_grasp`).
- **Used.** An :class:`ArmCorrection` gives the tool pose the corrected kinematics put the
  reported joints at (what the controller observes) and turns a tool target into the target to
  command so that the tool truly gets there; :class:`KinematicCorrection` follows each joint's
  play from the reports it sees and crosses a reversing joint's dead band in the command.

It reads only what a physical dVRK provides: the reported joints, the believed bases, the ECM's
reported pose, the stereo pair and its ``camera_info``.

- **Kept.** A registration is saved to a JSON file and loaded for the same robot
  (:func:`save_registration`, :func:`load_registration`), as a dVRK setup keeps its
  registration between runs; a study registers each robot once, whatever process runs its jobs.

Size: the fit, its use and its file stay together (one model of the arms' error, read and
written in one place).

Frames: ``world`` (as the robot believes it, the camera's through the ECM), the camera's left
optical frame ``camera``, each arm's RCM frame; 4x4 poses; metres, radians.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
import itertools
import json
import logging
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast
import weakref

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.control import Command, Controller, Observation
from suture_lfd.perception import detect_markers, stereo_from_camera_info
from suture_lfd.perception.instrument import InstrumentView, find_instrument
from suture_lfd.perception.window import points_window
from suture_lfd.skill.hysteresis import PSM_STILL, PlaysMemo, PlayTracker, TargetPlay, run_lengths

if TYPE_CHECKING:
    from sim_bridge.kinematics import PsmKinematics, SerialChain
    from sim_bridge.simulation import Simulation
    from suture_lfd.perception import StereoModel

_LOG = logging.getLogger(__name__)

# Registration poses: tool-tip offsets (m, world) from the centre of the markers seen (x
# towards the arm's own side: PSM1 left, PSM2 right), one arm after the other, and how long
# (s) the arm gets to reach each.
_SIDE = {'PSM1': -1.0, 'PSM2': 1.0}
# The last two visit the first two again from other directions: the same reported pose seen
# with the cables' slack taken up the other way shows the joints' dead band.
_SPOTS = ((-0.002, 0.002, 0.012), (0.002, 0.010, 0.016), (-0.004, 0.010, 0.012),
          (0.002, -0.002, 0.018), (-0.006, 0.006, 0.020), (0.004, 0.004, 0.010),
          (0.002, 0.010, 0.016), (-0.002, 0.002, 0.012))
_REACH_TIME = (1.2, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6)
_REVISITS = 2
_RETURN_TIME = 1.2
# Then, at the last spot, the wrist bent (joint index, rad) and straightened again before each
# look: straight from either side, the jaws' end shows the wrist's dead band (its roll stays
# unseen: a straight closed jaw looks the same rolled). Time (s) bent, and back straight.
_BENDS = ((4, 0.35), (4, -0.35), (5, 0.35), (5, -0.35))
_BEND_TIME, _BEND_BACK_TIME = 0.4, 0.6
# Points of the shaft's axis used in the fit: distances (m) behind the wrist-pitch axis.
_SHAFT_POINTS = (0.010, 0.030)
_X_SCALE = np.array([0.02, 0.02, 0.002, 0.002, 0.002, 0.002])
# Dead bands fitted: the joints (outer yaw, pitch, insertion, wrist pitch, wrist yaw), their
# scale and upper bound (rad, m).
_BAND_JOINTS = (0, 1, 2, 4, 5)
_BAND_SCALE = np.array([0.01, 0.01, 0.0005, 0.02, 0.02])
_BAND_MAX = np.array([0.05, 0.05, 0.002, 0.12, 0.12])
# Dead bands the fit starts from besides none: a dVRK's order (about 1 deg on the outer joints,
# half a millimetre on the insertion, a few degrees on the instrument's wrist; Hwang et al.
# 2020, Miyasaka et al. 2015). From none alone, the play at each pose would be set by the
# servo's last sub-band settling wiggle, and the fit stays at zero.
_BAND_START = np.array([0.0175, 0.0175, 0.0005, 0.05, 0.05])
# Largest offsets (rad, rad, m) and base translation (m, per axis) of a plausible fit: a dVRK's
# homing leaves a few degrees and millimetres, its camera registration "a 5 mm to 10 mm cube";
# a fit beyond is one of poses seen wrong.
_PLAUSIBLE = np.array([0.1, 0.1, 0.012, 0.015, 0.015, 0.015])
# The prior of the fit with dead bands (a dVRK-like arm): each offset and base coordinate costs
# _PRIOR_PX pixels per _PRIOR_SCALE (rad, rad, m, m, m, m; a dVRK's homing and camera
# registration, config/realism_arm.yaml's dvrk preset with the ECM's share). Its registration
# poses share nearly one shaft direction, along which an insertion offset and a base translation
# trade almost freely; a camera turned off by its ECM's error (a base rotation the fit does not
# model) slid such fits 10-20 mm along that valley, at a low residual, and left the tool 3-5 mm
# off where the shaft points elsewhere (the regrasp). One pixel per that scale is far below
# what the poses tell of any other direction.
_PRIOR_SCALE = np.array([0.035, 0.035, 0.003, 0.005, 0.005, 0.005])
_PRIOR_PX = 1.0
# The instrument's cable model a lab calibrates once per instrument type, not per robot
# (:meth:`KinematicCorrection.with_cable_model`): the wrist's stretch (true minus reported per
# unit deflection from straight: roll, wrist pitch, wrist yaw) and the roll's dead band (rad).
WRIST_STRETCH = (0.0, 0.0, 0.0, 0.03, 0.03, 0.03)
ROLL_BAND = 0.052
# Longest time (s) between two commands of an arm that continue one motion for the backlash
# inverse (:meth:`KinematicCorrection._to_play`): ten control periods of the study.
_COMMAND_GAP = 0.1
# A pose whose RMS residual (pixels) is above this after a first fit is left out.
_OUTLIER_PX = 2.0
# Pixels: the most a seen jaws' end SHORTER than the model's counts (:func:`_hidden_end`).
_HIDDEN_END_PX = 2.0
# A fit whose image residual (RMS, pixels) is above this is not trusted.
MAX_RESIDUAL_PX = 3.0
# One arm's joints (rad, m), and one registration pose as seen: reported joints, the camera's
# pose then (T_camera_world) and the instrument in the left and right images (None: not seen).
Joints = Sequence[float] | np.ndarray
Sample = tuple[np.ndarray, np.ndarray, 'InstrumentView | None', 'InstrumentView | None']


@dataclass(frozen=True, eq=False)
class ArmCorrection:
    """
    One arm's estimated kinematic error and what it changes.

    Attributes
    ----------
    arm : str
        ``'PSM1'`` or ``'PSM2'``.
    kinematics : sim_bridge.kinematics.PsmKinematics
        The arm's kinematic model.
    T_world_base : ndarray, shape (4, 4)
        The arm's believed base (its registration, as it reports poses).
    joint_offset : ndarray, shape (6,)
        Estimated true minus reported joints (rad, m): the first three from the registration,
        the wrist's roll and pitch from the held needle (:meth:`with_wrist_offset`).
    translation : ndarray, shape (3,)
        Estimated true minus believed base position (m, ``world``).
    residual_px : float
        RMS image residual of the fit (pixels).
    backlash : ndarray, shape (6,)
        Estimated full dead band per joint (rad, m; the instrument's roll not fitted, 0 where
        no backlash was found): the play (:mod:`suture_lfd.skill.hysteresis`) adds to the
        offsets, following the direction each joint last moved in.
    stretch : ndarray, shape (6,)
        Per joint, the cables' stretch: true minus reported joint per unit of the reported
        joint's deflection from ``neutral`` (dimensionless; default none). Not fitted by the
        registration: a compliance known for the instrument (:func:`with_cable_model`).
    neutral : ndarray, shape (6,)
        Joints (rad, m) at which the cables carry no extra load (the wrist straight).

    """

    arm: str
    kinematics: 'SerialChain'
    T_world_base: np.ndarray
    joint_offset: np.ndarray
    translation: np.ndarray
    residual_px: float = 0.0
    backlash: np.ndarray = field(default_factory=lambda: np.zeros(6))
    stretch: np.ndarray = field(default_factory=lambda: np.zeros(6))
    neutral: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @cached_property
    def _constants(self) -> tuple[list[float], list[tuple[float, float]] | None]:
        """The offsets and (when modelled) each joint's stretch and neutral, as plain floats."""
        stretch = (list(zip(np.asarray(self.stretch, dtype=float).tolist(),
                            np.asarray(self.neutral, dtype=float).tolist()))
                   if np.any(self.stretch) else None)
        return np.asarray(self.joint_offset, dtype=float).tolist(), stretch

    @cached_property
    def T_base_world(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """The inverse of the believed base (read-only; it runs every control step)."""
        T = invert_transform(self.T_world_base)
        T.flags.writeable = False
        return T

    def _true_joints(self, q: Joints) -> list[float]:
        """Return the reported joints ``q`` with the offsets and (when modelled) the stretch."""
        values = q.tolist() if isinstance(q, np.ndarray) else [float(v) for v in q]
        offsets, stretch = self._constants
        qt = [a + b for a, b in zip(values, offsets)]
        if stretch is not None:
            for j, (k, n) in enumerate(stretch):
                qt[j] += k * (values[j] - n)
        return qt

    def tool_pose(self, q: Joints, play: Sequence[float] | None = None) -> np.ndarray:
        """
        Tool-tip pose (4, 4, ``world``) where the corrected kinematics put the joints ``q``.

        Parameters
        ----------
        q : array_like, shape (6,)
            Reported joints (rad, m).
        play : sequence of float, optional
            The joints' backlash play now (rad, m; :class:`~suture_lfd.skill.hysteresis.
            PlayTracker`), leading joints; default none.

        """
        # the reported joints are valid (the arm's own), the offsets a few degrees and
        # millimetres: no check, scalar forward kinematics (it runs every control step)
        qt = self._true_joints(q)
        if play is not None:
            for j, p in enumerate(play):
                qt[j] += p
        T = self.T_world_base @ self.kinematics.fk_unchecked(qt)
        T[:3, 3] += self.translation
        return T

    def error(self, q: Joints, play: Sequence[float] | None = None) -> np.ndarray:
        """
        Return the world-frame error ``E`` at joints ``q``: true pose = ``E @`` reported pose.

        Parameters
        ----------
        q : array_like, shape (6,)
            Reported joints.
        play : sequence of float, optional
            The joints' backlash play now (see :meth:`tool_pose`).

        Returns
        -------
        ndarray, shape (4, 4)

        """
        # the arm's own valid joints: the unchecked forward kinematics gives the same floats
        reported = self.T_world_base @ self.kinematics.fk_unchecked(
            np.asarray(q, dtype=float).tolist())
        return self.tool_pose(q, play) @ invert_transform(reported)


    def wrist_change(self, q: Joints, offsets: Sequence[float]) -> np.ndarray:
        """
        Return the tool-frame change (4, 4) of the wrist's joints ``offsets`` more than now.

        The tool truly at ``T`` (``world``) with its wrist's first joints (the instrument's
        roll, then the wrist pitch, ...) ``offsets`` (rad) further is at ``T @`` this: the arm's
        outer joints and base do not move.

        Parameters
        ----------
        q : array_like, shape (6,)
            Reported joints.
        offsets : sequence of float
            Offsets (rad) of joints 4, 5, ... (indices 3, 4, ...).

        """
        qt = self._true_joints(q)
        moved = list(qt)
        for j, d in enumerate(offsets):
            moved[3 + j] += float(d)
        return invert_transform(self.kinematics.fk_unchecked(qt)) \
            @ self.kinematics.fk_unchecked(moved)

    def with_wrist_offset(self, offsets: 'Sequence[float] | np.ndarray') -> 'ArmCorrection':
        """Return this correction with ``offsets`` (rad) added to joints 4, 5, ... ."""
        joint_offset = np.array(self.joint_offset, dtype=float)
        joint_offset[3:3 + len(offsets)] += np.asarray(offsets, dtype=float)
        return replace(self, joint_offset=joint_offset)


class KinematicCorrection:
    """
    The PSMs' corrections: observations as the tools truly are, commands that get them there.

    Parameters
    ----------
    arms : dict of str to ArmCorrection
        Corrected arms (others pass unchanged).

    """

    def __init__(self, arms: Mapping[str, ArmCorrection]) -> None:
        self.arms = dict(arms)
        # per arm: (joints' bytes, error E) or (joints' bytes, error E, corrected tool pose)
        self._cache: dict[str, tuple[Any, ...]] = {}
        # the backlash play of the arms with a dead band, advanced by each new report
        self._plays = {arm: PlayTracker(fit.backlash) for arm, fit in self.arms.items()
                       if np.any(np.asarray(fit.backlash) > 0.0)}
        #: the backlash inverse judges a joint's direction from its targets (True) or, as
        #: before, from the target against the reported joints (False: the lagging motor's
        #: overshoot then reads as a reversal, and a joint cycles by its band)
        self.inverse_on_targets = True
        self._inverse: dict[str, TargetPlay] = {}

    def set_arm(self, fit: ArmCorrection) -> None:
        """Correct ``fit.arm`` with ``fit`` from now on (its dead bands' play kept)."""
        self.arms[fit.arm] = fit
        self._cache.pop(fit.arm, None)

    def with_cable_model(self, stretch: ArrayLike = WRIST_STRETCH,
                         roll_band: float = ROLL_BAND) -> None:
        """
        Add the instrument's known cable model to every arm (in place, before its first use).

        The registration sees the wrist too weakly to fit its cables: the instrument's roll
        looks the same rolled, and the wrist's stretch (proportional to its deflection from
        straight) is all but nil at the straight poses it looks at. A dVRK lab knows both for
        its instrument from a bench calibration (Haghighipanah et al., IROS 2016: a cable's
        stretch is proportional to its tension; Hwang et al., RA-L 2020: the dead bands); here
        they are given: ``stretch`` (6, per unit deflection from the joints' zero) and the
        roll's dead band ``roll_band`` (rad; 0 keeps the fitted one).

        """
        for arm, fit in list(self.arms.items()):
            backlash = np.array(fit.backlash, dtype=float)
            if roll_band > 0.0:
                backlash[3] = roll_band
            self.arms[arm] = replace(fit, backlash=backlash,
                                     stretch=np.asarray(stretch, dtype=float).copy(),
                                     neutral=np.zeros(6))
            self._plays[arm] = PlayTracker(backlash)
            self._inverse.pop(arm, None)
        self._cache.clear()

    def _play(self, arm: str, q: Joints) -> list[float] | None:
        """Return the arm's play at its new reported joints ``q`` (None: no backlash)."""
        tracker = self._plays.get(arm)
        return None if tracker is None else tracker.update(q)

    def _error(self, arm: str, q: Joints) -> np.ndarray:
        key = np.asarray(q, dtype=float).tobytes()
        hit = self._cache.get(arm)
        if hit is not None and hit[0] == key:
            return hit[1]
        E = self.arms[arm].error(q, self._play(arm, q))
        self._cache[arm] = (key, E)
        return E

    def observe(self, obs: Observation) -> Observation:
        """
        Return ``obs`` with each corrected arm's tool pose where the correction puts it.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            With reported tool poses and the reported joints ``q``.

        Returns
        -------
        sim_bridge.control.Observation

        """
        if not self.arms or obs.q is None:
            return obs
        tools = dict(obs.T_world_tool)
        for arm, fit in self.arms.items():
            q = obs.q.get(arm)
            if arm in tools and q is not None:
                key = np.asarray(q, dtype=float).tobytes()
                hit = self._cache.get(arm)
                if hit is None or hit[0] != key or len(hit) < 3:
                    # the corrected pose straight from the joints (one forward kinematics), and
                    # the error against the reported pose at hand, kept for the command
                    # (the play advances once per new report: a report the command already
                    # took has its play taken)
                    tracker = self._plays.get(arm)
                    play = (self._play(arm, q) if hit is None or hit[0] != key
                            else None if tracker is None else list(tracker.play))
                    T = fit.tool_pose(q, play)
                    T.flags.writeable = False
                    reported = np.asarray(obs.T_world_tool[arm], dtype=float)
                    hit = (key, T @ invert_transform(reported), T)
                    self._cache[arm] = hit
                tools[arm] = hit[2]  # an arm standing still: the same pose as before
        return Observation(t=obs.t, T_world_tool=tools, jaw=obs.jaw,
                           T_world_needle=obs.T_world_needle, holders=obs.holders,
                           pair=obs.pair, T_world_base=obs.T_world_base, q=obs.q)

    def command(self, cmd: Command, q: Mapping[str, Any]) -> Command:
        """
        Return ``cmd`` with each tool target turned into what to command the arm.

        Parameters
        ----------
        cmd : sim_bridge.control.Command
            Targets where the tools should truly be (``world``).
        q : dict of str to ndarray
            The arms' reported joints now (the error is taken there: it changes little
            between two commands).

        Returns
        -------
        sim_bridge.control.Command

        """
        if not self.arms or not cmd.T_world_tool:
            return cmd
        tools = dict(cmd.T_world_tool)
        for arm, T in tools.items():
            if T is None or arm not in self.arms or q.get(arm) is None:
                continue
            target = invert_transform(self._error(arm, q[arm])) @ np.asarray(T, dtype=float)
            tracker = self._plays.get(arm)
            if tracker is not None and self.inverse_on_targets:
                target = self._to_play(arm, tracker, q[arm], target, T, float(cmd.t))
            elif tracker is not None:
                target = self._across_play(arm, tracker, q[arm], target, T)
            tools[arm] = target
        return Command(t=cmd.t, T_world_tool=tools, jaw=cmd.jaw, subtask=cmd.subtask)

    def _to_play(self, arm: str, tracker: PlayTracker, q: Joints, target: np.ndarray,
                 T: ArrayLike, t: float) -> np.ndarray:
        """
        Return the command for the pose ``T`` with the play the joints will have there.

        ``target`` is the command with the present play. Where the joints should truly go is
        the corrected kinematics' inverse of ``T`` (less the offsets: in the reports' terms);
        its direction from one command to the next (:class:`~suture_lfd.skill.hysteresis.
        TargetPlay`) sets the play of this command. A command more than
        :data:`_COMMAND_GAP` after the last (or before it: a new episode) starts from the
        present play, with no direction.
        """
        fit = self.arms[arm]
        inverse = self._inverse.get(arm)
        if inverse is None:
            inverse = self._inverse[arm] = TargetPlay(fit.backlash, PSM_STILL)
        fresh = inverse.t is None or not 0.0 <= t - inverse.t <= _COMMAND_GAP
        play = list(tracker.play) if fresh or inverse.play is None else inverse.play
        offset = fit._constants[0]  # the offsets as plain floats, kept per fit
        try:
            goal = np.array(T, dtype=float)
            goal[:3, 3] -= fit.translation
            chain = cast('PsmKinematics', fit.kinematics)  # a PSM's: it has an inverse
            true_q = chain.ik_unchecked(fit.T_base_world @ goal,
                                        [float(a) + b + p for a, b, p in zip(q, offset, play)])
        except ValueError:
            return target  # out of reach: the arm will say so for the command itself
        load = [float(a) - b for a, b in zip(true_q, offset)]
        if fresh or inverse.play is None:
            inverse.start(play, load)
        inverse.t = t
        heading = inverse.update(load, q, tracker.play)
        if heading == tracker.play:
            return target
        return invert_transform(fit.error(q, heading)) @ np.asarray(T, dtype=float)

    def _across_play(self, arm: str, tracker: PlayTracker, q: Joints, target: np.ndarray,
                     T: ArrayLike) -> np.ndarray:
        """
        Return the command for the pose ``T`` with the play the joints will have on the way.

        ``target`` is the command with the present play; the joints it asks for (the arm's
        own inverse kinematics) tell each joint's direction, and a joint about to reverse gets
        its dead band crossed in this command (:meth:`PlayTracker.heading`).
        """
        fit = self.arms[arm]
        values = q.tolist() if isinstance(q, np.ndarray) else [float(v) for v in q]
        try:
            local = fit.T_base_world @ target
            chain = cast('PsmKinematics', fit.kinematics)  # a PSM's: it has an inverse
            q_to = chain.ik_unchecked(local, values)
        except ValueError:
            return target  # out of reach: the arm will say so for the command itself
        play = tracker.heading(values, q_to, PSM_STILL)
        if play == tracker.play:
            return target
        return invert_transform(fit.error(q, play)) @ np.asarray(T, dtype=float)


class CorrectedController:
    """
    A controller run on corrected kinematics.

    It sees the tools where they are; its tool targets are turned into what to command.

    Parameters
    ----------
    controller : object
        ``reset(obs)``, ``step(obs) -> Command``, ``done``; it is given observations already
        corrected (:meth:`KinematicCorrection.observe`, e.g. by the observer).
    correction : KinematicCorrection

    """

    def __init__(self, controller: Controller, correction: KinematicCorrection) -> None:
        self.controller = controller
        self.correction = correction

    @property
    def done(self) -> bool:
        """Whether the controller is done."""
        return self.controller.done

    def reset(self, obs: Observation) -> None:
        """Reset the controller."""
        self.controller.reset(obs)

    def step(self, obs: Observation) -> Command:
        """Return the controller's command, tool targets turned into what to command."""
        cmd = self.controller.step(obs)
        return self.correction.command(cmd, obs.q or {})


def _model_points(kinematics: 'SerialChain', T_world_base: np.ndarray, q: ArrayLike,
                  x: np.ndarray, jaw: Sequence[float],
                  memo: dict[bytes, np.ndarray] | None = None) -> np.ndarray:
    """
    World points of the straight instrument: two shaft-axis points, then the closed jaws' end.

    ``jaw`` is ``(length, width, thickness)`` (m) of the closed jaws: their end face's centre
    and its four corners follow the two shaft points. ``memo`` (joints' bytes -> the points
    before the translation ``x[3:6]``) spares the kinematics of joints seen before: a fit's
    finite differences in the base translation move no joint.
    """
    d = np.zeros(6)
    d[:3] = x[:3]
    qd = np.asarray(q, dtype=float) + d
    key = qd.tobytes() if memo is not None else b''
    pts = memo.get(key) if memo is not None else None
    if pts is None:
        pts = _chain_points(kinematics, T_world_base, qd, jaw)
        if memo is not None:
            if len(memo) > 4096:
                memo.clear()
            memo[key] = pts
    return pts + x[3:6]


def _chain_points(kinematics: 'SerialChain', T_world_base: np.ndarray, qd: np.ndarray,
                  jaw: Sequence[float]) -> np.ndarray:
    """:func:`_model_points` at the joints ``qd`` (offsets added), before the translation."""
    length, width, thickness = jaw
    # the link's and the tip's floats (rotation rows, translation): the same operations as on
    # their 4x4 arrays, without making them
    link4, tip = kinematics.wrist_and_tip_values(qd.tolist(), 4)
    _, _, c, _, _, f, _, _, i, x, y, z = link4
    local: list[Any] = [(x - s * c, y - s * f, z - s * i) for s in _SHAFT_POINTS]
    end = np.array((tip[9] + length * tip[2], tip[10] + length * tip[5],
                    tip[11] + length * tip[8]))
    local.append(end)
    R = np.array(tip[:9]).reshape(3, 3)
    for a, b in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        local.append(end + R @ np.array([0.5 * a * width, b * thickness, 0.0]))
    return np.array(local) @ T_world_base[:3, :3].T + T_world_base[:3, 3]


def _hidden_end(along: float) -> float:
    """
    Return the jaws' end residual ``along`` (pixels: model's end beyond the seen end), capped.

    Of a pose whose jaws' end may be hidden (:func:`_robust_fit`): a seen end short of the
    model's counts up to :data:`_HIDDEN_END_PX` (a smooth cap, the same as the residual near
    zero); a seen end beyond the model's end has no such excuse and counts in full.
    """
    if along <= 0.0:
        return along
    return _HIDDEN_END_PX * math.tanh(along / _HIDDEN_END_PX)


def _robust_fit(used: list[Any], x_start: np.ndarray, solve: Any, residuals: Any,
                arm: str, hidden: set[int]) -> tuple[Any, list[Any]]:
    """
    Fit ``used`` poses, leaving out those whose image disagrees with the others.

    A pose seen wrong (another dark thing taken for the shaft) is left out and the rest fitted
    again; when so many disagree that the fit of all of them is the outliers', each subset of
    three poses is fitted alone and the one the most poses agree with is kept.

    In the subsets' count, a pose whose jaws' end may be hidden (dipping into the pad at a low
    pose, or otherwise cut short in the image) agrees when it would with its end's residual
    capped (``residuals(x, poses, True)``: :func:`_hidden_end`); such a pose, when it
    disagrees in full with the subset kept, is added to ``hidden`` (the indices, ``pose[4]``,
    of the poses whose end residual ``residuals`` caps) and kept. Several low poses each seen
    shorter would otherwise agree with one another on a shorter instrument and, as many as the
    rest, could win the count; the cap is one-sided, so the poses whose end is seen in full
    still refuse that instrument. (The fit of every pose is judged in full: a wrong one would
    let poses seen shorter agree.)

    Returns
    -------
    tuple
        The least-squares result and the poses it was fitted to.

    """
    def per_pose(x: np.ndarray, eased: bool = True) -> np.ndarray:
        r = residuals(x, used, eased).reshape(len(used), -1)
        return np.sqrt(np.mean(r ** 2, axis=1))

    def ease(x: np.ndarray) -> bool:
        """Add to ``hidden`` the poses that agree at ``x`` only with their end capped."""
        short = (per_pose(x) <= _OUTLIER_PX) & (per_pose(x, False) > _OUTLIER_PX)
        new = {u[4] for u, s in zip(used, short) if s} - hidden
        hidden.update(new)
        return bool(new)

    fit = solve(used, x_start)
    x0 = fit.x
    errors = per_pose(x0, False)
    good = errors <= _OUTLIER_PX
    _LOG.debug('%s per-pose residuals %s', arm, errors.round(2))
    if good.sum() < 3 and len(used) > 3:
        best: tuple[int, float, np.ndarray] | None = None
        for subset in itertools.combinations(range(len(used)), 3):
            x = solve([used[i] for i in subset], x_start).x
            errors = per_pose(x)
            agree = errors <= _OUTLIER_PX
            key = (int(agree.sum()), -float(errors[agree].mean()) if agree.any() else 0.0)
            if best is None or key > best[:2]:
                best = (*key, x)
        assert best is not None
        x0 = best[2]
        if ease(x0):
            _LOG.debug("%s: jaws' end maybe hidden at poses %s", arm, sorted(hidden))
        good = per_pose(x0, False) <= _OUTLIER_PX
        _LOG.debug('%s: %d of %d poses agree with the best subset', arm, good.sum(), len(used))
        if good.all():
            fit = solve(used, x0)
    if not good.all() and good.sum() >= 3:
        used = [s for s, g in zip(used, good) if g]
        fit = solve(used, x0)
    return fit, used


def fit_arm_correction(arm: str, kinematics: 'SerialChain', T_world_base: np.ndarray,
                       samples: Sequence[Sample], stereo: 'StereoModel',
                       jaw: Sequence[float],
                       paths: Sequence[ArrayLike] | None = None) -> ArmCorrection:
    """
    Fit an arm's joint offsets and base translation to what the camera saw at a few poses.

    Parameters
    ----------
    arm : str
        Arm name.
    kinematics : sim_bridge.kinematics.PsmKinematics
        Its kinematic model.
    T_world_base : ndarray, shape (4, 4)
        Its believed base (``world``).
    samples : sequence of tuple
        ``(q, T_camera_world, view_left, view_right)`` per pose: reported joints, the camera
        pose then, and the :class:`~suture_lfd.perception.instrument.InstrumentView` of the
        instrument in each image (None when not seen).
    stereo : suture_lfd.perception.StereoModel
        The camera model.
    jaw : tuple of float
        ``(length, width, thickness)`` (m) of the closed jaws (the instrument's model).
    paths : sequence of array_like, optional
        Per sample, the joints the arm reported on its way there (shape ``(m, 6)``, ending at
        the sample). Given, the dead bands of the outer joints, the insertion and the wrist's
        pitch and yaw are fitted too: their play at each pose follows from the motion
        (:func:`suture_lfd.skill.hysteresis.plays_at`).

    Returns
    -------
    ArmCorrection

    Raises
    ------
    ValueError
        With fewer than three poses seen in both images, or paths not one per sample.

    """
    if paths is not None and len(paths) != len(samples):
        raise ValueError(f'{arm}: {len(paths)} motion paths for {len(samples)} registration '
                         'poses; one per pose is needed')
    runs = None if paths is None else run_lengths(paths, 6)
    n_b = len(_BAND_JOINTS)
    # seen in both images: no view is None; each kept with its pose's index (its play)
    used = cast(list[tuple[np.ndarray, np.ndarray, InstrumentView, InstrumentView, int]],
                [(*s, k) for k, s in enumerate(samples)
                 if s[2] is not None and s[3] is not None])
    if len(used) < 3:
        raise ValueError(f'{arm}: its instrument was seen in both images at {len(used)} of '
                         f'{len(samples)} registration poses; 3 are needed')
    x_scale = _X_SCALE if runs is None else np.concatenate([_X_SCALE, _BAND_SCALE])
    bounds = (-np.inf, np.inf) if runs is None else (
        np.concatenate([np.full(6, -np.inf), np.zeros(n_b)]),
        np.concatenate([np.full(6, np.inf), _BAND_MAX]))

    def bands(x: np.ndarray) -> np.ndarray:
        full = np.zeros(6)
        full[list(_BAND_JOINTS)] = x[6:]
        return full

    memo: dict[bytes, np.ndarray] = {}
    # each joint's plays per band: a finite difference moves one band, or none
    plays_at = None if runs is None else PlaysMemo(runs)

    # poses whose jaws' end may be hidden: their end's residual is capped (_robust_fit)
    hidden: set[int] = set()

    # the camera's constants as StereoModel.project reads them (the same floats)
    fx, fy, cx, cy = stereo.fx, stereo.fy, stereo.cx, stereo.cy
    fx_b = stereo.fx * stereo.baseline
    views: dict[int, tuple[Any, ...]] = {}

    def axes(poses: list[Any]) -> tuple[Any, ...]:
        """Per image (left, right): each pose's seen axis point, direction and end."""
        hit = views.get(id(poses))
        if hit is None or hit[0] is not poses:
            arrays = tuple(np.array([getattr(u[2 + side], name) for u in poses])
                           for side in (0, 1) for name in ('point', 'direction', 'end'))
            hit = views[id(poses)] = (poses, *arrays)
        return hit[1:]

    def residuals(x: np.ndarray, poses: list[Any], eased: bool = False) -> np.ndarray:
        """
        Image residuals; ``eased``: every pose's end residual capped as if maybe hidden.

        Per pose, in each image (left, right): the two shaft points' distances from the seen
        axis, the jaws' end along it (the corner of their end face farthest along the axis),
        the end face centre's distance from the axis. Every pose is projected at once, with
        the operations of :meth:`StereoModel.project` and :class:`InstrumentView` (the same
        floats as pose by pose).
        """
        plays = None if len(x) == 6 or plays_at is None else plays_at(bands(x))
        pcs = []
        for q, T_cw, _, _, k in poses:
            if plays is not None:
                q = np.asarray(q, dtype=float) + plays[k]
            pts = _model_points(kinematics, T_world_base, q, x, jaw, memo)
            pcs.append(pts @ T_cw[:3, :3].T + T_cw[:3, 3])
        n = len(poses)
        P = np.concatenate(pcs).reshape(n, -1, 3)
        z = P[:, :, 2]
        u = fx * P[:, :, 0] / z + cx
        v = fy * P[:, :, 1] / z + cy
        seen = axes(poses)
        out = np.empty((n, 2, 4))
        for side, us in enumerate((u, u - fx_b / z)):
            point, direction, end = seen[3 * side:3 * side + 3]
            # distance: (uv - point) x direction; along: (uv - end) . direction (a matmul)
            dist = (us[:, :3] - point[:, 0:1]) * direction[:, 1:2] \
                - (v[:, :3] - point[:, 1:2]) * direction[:, 0:1]
            corners = np.stack((us[:, 3:], v[:, 3:]), axis=-1) - end[:, None, :]
            out[:, side, 0:2] = dist[:, :2]
            out[:, side, 2] = np.matmul(corners, direction[:, :, None])[..., 0].max(axis=1)
            out[:, side, 3] = dist[:, 2]
        for i, pose in enumerate(poses):
            if eased or pose[4] in hidden:
                for side in (0, 1):
                    out[i, side, 2] = _hidden_end(float(out[i, side, 2]))
        return out.ravel()

    prior = None if runs is None else _PRIOR_PX / _PRIOR_SCALE

    def fitted(x: np.ndarray, poses: list[Any]) -> np.ndarray:
        """Return the residuals the fit minimises: the images', and with dead bands the prior's."""
        r = residuals(x, poses)
        return r if prior is None else np.concatenate([r, prior * x[:6]])

    def solve(poses: list[Any], x0: np.ndarray) -> Any:
        if len(x0) == 6:
            return least_squares(fitted, x0, args=(poses,), x_scale=_X_SCALE,
                                 loss='soft_l1', f_scale=2.0)
        return least_squares(fitted, x0, args=(poses,), x_scale=x_scale, loss='soft_l1',
                             f_scale=2.0, bounds=bounds)

    def per_pose(x: np.ndarray, poses: list[Any]) -> np.ndarray:
        return np.sqrt(np.mean(residuals(x, poses).reshape(len(poses), -1) ** 2, axis=1))

    def pruned(x0s: Sequence[np.ndarray]) -> Any:
        """Return the best fit of every pose from the starts ``x0s``, refit without those off."""
        best = min((solve(used, x0) for x0 in x0s), key=lambda r: r.cost)
        good = per_pose(best.x, used) <= _OUTLIER_PX
        if not good.all() and good.sum() >= 3:
            best = solve([u for u, g in zip(used, good) if g], best.x)
        return best

    # Candidates: the offsets and base translation alone, fitted to the spots visited once
    # with the poses seen wrong left out (the revisits and the bends, at spots seen already,
    # would let a fit of poses seen wrong agree with many at once); with dead bands, the
    # bands fitted to every pose from no bands and from a dVRK's, and from the offsets' fit.
    # Kept: the plausible one (offsets and base within a dVRK's calibration) that the most
    # poses agree with, then the smaller residual.
    spots = ([u for u in used if u[4] < len(_SPOTS) - _REVISITS] if runs is not None
             else used)
    if len(spots) < 3:
        spots = used
    fit, kept = _robust_fit(spots, np.zeros(6), solve, residuals, arm, hidden)
    if runs is None:
        used = kept
    else:
        # the revisits and the bends (at the last spot) of a spot whose jaws' end may be
        # hidden: the same pose, its end as hidden
        low = {_SPOTS[min(k, len(_SPOTS) - 1)] for k in hidden}
        hidden.update(u[4] for u in used if _SPOTS[min(u[4], len(_SPOTS) - 1)] in low)
        candidates = [fit,
                      pruned([np.zeros(6 + n_b), np.concatenate([np.zeros(6), _BAND_START])]),
                      pruned([np.concatenate([fit.x, np.zeros(n_b)]),
                              np.concatenate([fit.x, _BAND_START])])]

        def rank(r: Any) -> tuple[bool, int, float]:
            errors = per_pose(r.x, used)
            agree = errors <= _OUTLIER_PX
            plausible = bool(np.all(np.abs(r.x[:6]) <= _PLAUSIBLE))
            return (plausible, int(agree.sum()),
                    -float(errors[agree].mean()) if agree.any() else 0.0)

        fit = max(candidates, key=rank)
    rms = float(np.sqrt(np.mean((fit.fun if prior is None else fit.fun[:-6]) ** 2)))
    offset = np.zeros(6)
    offset[:3] = fit.x[:3]
    band = np.zeros(6) if len(fit.x) == 6 else bands(fit.x)
    _LOG.info('%s registration: joint offsets %s deg/mm, base %s mm, dead bands %s deg/mm, '
              'residual %.2f px', arm,
              np.round([np.degrees(offset[0]), np.degrees(offset[1]), 1e3 * offset[2]], 2),
              np.round(1e3 * fit.x[3:6], 2),
              np.round([np.degrees(band[0]), np.degrees(band[1]), 1e3 * band[2],
                        *np.degrees(band[3:])], 2), rms)
    return ArmCorrection(arm=arm, kinematics=kinematics, T_world_base=np.array(T_world_base),
                         joint_offset=offset, translation=fit.x[3:6].copy(), residual_px=rms,
                         backlash=band)


def _straight_pose(rcm: np.ndarray, tip: np.ndarray, T_now: np.ndarray) -> np.ndarray:
    """Tool pose at ``tip`` with its z along the shaft from the RCM ``rcm`` (wrist straight)."""
    z = tip - rcm
    z /= np.linalg.norm(z)
    x = T_now[:3, 0] - (T_now[:3, 0] @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, tip
    return T


def bent_pose(kinematics: 'PsmKinematics', T_world_base: np.ndarray, straight: np.ndarray,
              q_ref: Joints, joint: int, angle: float) -> np.ndarray:
    """
    Return the tool pose (``world``) of ``straight`` with one wrist joint turned by ``angle``.

    Parameters
    ----------
    kinematics : sim_bridge.kinematics.PsmKinematics
    T_world_base : ndarray, shape (4, 4)
        The arm's believed base.
    straight : ndarray, shape (4, 4)
        A registration pose (wrist straight).
    q_ref : array_like, shape (6,)
        Reported joints near it (the inverse kinematics' reference).
    joint : int
        Joint index (4: wrist pitch, 5: wrist yaw).
    angle : float
        Turn (rad).

    """
    q = kinematics.ik(invert_transform(T_world_base) @ straight, q_ref).copy()
    q[joint] += angle
    return T_world_base @ kinematics.fk(q)


def _markers_centre(sim: 'Simulation', stereo: 'StereoModel') -> np.ndarray | None:
    """Centre (m, ``world``) of every marker seen in the stereo pair, or None."""
    _, frame = sim.endoscope_frame()  # searched for: the whole frame
    found = detect_markers(frame.left_rgb, frame.right_rgb, stereo)
    points = np.vstack([np.asarray(found.entries, dtype=float).reshape(-1, 3),
                        np.asarray(found.exits, dtype=float).reshape(-1, 3)])
    points = points[np.isfinite(points).all(axis=1)]
    if not len(points):
        return None
    T = sim.reported_tool_pose('ECM') @ sim.camera.T_tip_left
    return T[:3, :3] @ points.mean(axis=0) + T[:3, 3]


#: m: how far an instrument may be from where its kinematics put it at a registration pose (a
#: dVRK's arms are within a 5-10 mm cube of it): the window looked at is widened by it.
LOOK_MARGIN = 0.012


def _look_at(sim: 'Simulation', arm: str, stereo: 'StereoModel',
             jaw: Sequence[float]) -> Sample:
    """
    Look at ``arm``'s instrument near where its kinematics put it.

    The endoscope's images (:meth:`sim_bridge.simulation.Simulation.endoscope_frame`: the
    delivered frame, with a frame timing) in the window around the instrument's expected
    projection and :data:`LOOK_MARGIN` (the whole frame when that window is most of it); the
    views found there are given in the whole frame's pixels.
    """
    T_cw = invert_transform(sim.reported_tool_pose('ECM') @ sim.camera.T_tip_left)
    q = np.array(sim.reported_jp(arm), dtype=float)
    pts = _model_points(sim.kinematics[arm], sim.believed_base(arm), q, np.zeros(6), jaw)
    pc = pts @ T_cw[:3, :3].T + T_cw[:3, 3]
    uv_l, uv_r = stereo.project(pc)
    # the shaft's axis (its points fitted), the jaws and the margin
    window = points_window(stereo, pc, LOOK_MARGIN)
    _, frame = sim.endoscope_frame(window)
    offset = np.zeros(2) if window is None else np.array(window[:2], dtype=float)
    views = []
    for img, uv in ((frame.left_rgb, uv_l), (frame.right_rgb, uv_r)):
        view = find_instrument(img, uv[:2] - offset, uv[2] - offset)
        views.append(None if view is None else replace(
            view, point=view.point + offset, end=view.end + offset))
    return q, T_cw, views[0], views[1]


def _visit(sim: 'Simulation', arm: str, centre: np.ndarray, start: np.ndarray,
           stereo: 'StereoModel', jaw: Sequence[float]
           ) -> tuple[list[Sample], list[np.ndarray]]:
    """Take ``arm`` to the registration poses; return what was seen and the joints on the way."""
    rcm = sim.believed_base(arm)[:3, 3]
    samples: list[Sample] = []
    paths: list[np.ndarray] = []
    path = [np.array(sim.reported_jp(arm), dtype=float)]

    def go(target: np.ndarray, wait: float) -> None:
        sim.apply(Command(t=sim.time, T_world_tool={arm: target}, jaw={arm: 0.0},
                          subtask='registration'))
        # the joints as reported on the way (the dead bands' play follows from them)
        for _ in range(int(round(wait / sim.dt))):
            sim.step()
            path.append(np.array(sim.reported_jp(arm), dtype=float))

    def look() -> None:
        paths.append(np.array(path))
        del path[:-1]
        samples.append(_look_at(sim, arm, stereo, jaw))

    target = start
    for spot, wait in zip(_SPOTS, _REACH_TIME):
        tip = centre + np.array([_SIDE[arm] * spot[0], spot[1], spot[2]])
        target = _straight_pose(rcm, tip, start)
        go(target, wait)
        look()
    for joint, angle in _BENDS:
        go(bent_pose(cast('PsmKinematics', sim.kinematics[arm]), sim.believed_base(arm), target,
                     sim.arms[arm].measured_jp, joint, angle), _BEND_TIME)
        go(target, _BEND_BACK_TIME)
        look()
    return samples, paths


_REGISTERED: 'weakref.WeakKeyDictionary[Simulation, KinematicCorrection]' = \
    weakref.WeakKeyDictionary()


def register_arms(sim: 'Simulation', seed: int = 0,
                  dead_bands: bool = True) -> KinematicCorrection:
    """
    Register both PSMs against the endoscope in-process (once per simulation: kept for it).

    The scene is reset with ``seed`` and homed, the markers are looked for (the registration
    poses are around their centre), each PSM in turn is moved to the registration poses, seen
    and sent back; the caller starts its own episode afterwards. The result is kept for
    ``sim`` (a robot's errors do not change while it runs), so that every throw on it uses the
    same correction whatever ran before.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
    seed : int
        Scene seed of the registration run.
    dead_bands : bool
        Fit the joints' dead bands too (the correction then follows their play); False: offsets
        and base translation only (for comparison).

    Returns
    -------
    KinematicCorrection
        The arms whose fit was trusted (an arm not seen well enough is left uncorrected, and
        none when the markers are not seen).

    """
    known = _REGISTERED.get(sim)
    if known is not None:
        return known
    sim.reset(seed=seed)
    sim.enable_and_home_all()
    camera = sim.camera
    stereo = stereo_from_camera_info(camera.camera_info('left'), camera.camera_info('right'))
    shape = sim.config.world.instrument  # the instrument's model, as its maker gives it
    jaw = (shape.jaw_length, shape.jaw_width, shape.jaw_thickness)
    centre = _markers_centre(sim, stereo)
    if centre is None:
        _LOG.warning('registration: no marker seen to place the registration poses')
        correction = KinematicCorrection({})
        _REGISTERED[sim] = correction
        return correction
    start = {a: sim.reported_tool_pose(a) for a in PSMS}
    samples: dict[str, list[Sample]] = {a: [] for a in PSMS}
    paths: dict[str, list[np.ndarray]] = {a: [] for a in PSMS}
    for arm in PSMS:
        samples[arm], paths[arm] = _visit(sim, arm, centre, start[arm], stereo, jaw)
        sim.apply(Command(t=sim.time, T_world_tool={arm: start[arm]}, jaw={},
                          subtask='registration'))
        sim.run(_RETURN_TIME)
    arms: dict[str, ArmCorrection] = {}
    for arm in PSMS:
        try:
            fit = fit_arm_correction(arm, sim.kinematics[arm], sim.believed_base(arm),
                                     samples[arm], stereo, jaw,
                                     paths[arm] if dead_bands else None)
        except ValueError as exc:
            _LOG.warning('registration: %s', exc)
            continue
        if fit.residual_px > MAX_RESIDUAL_PX:
            _LOG.warning('registration of %s not trusted: residual %.1f px', arm,
                         fit.residual_px)
            continue
        arms[arm] = fit
    correction = KinematicCorrection(arms)
    _REGISTERED[sim] = correction
    return correction


#: Format name and version of a saved registration (:func:`save_registration`).
REGISTRATION_FORMAT, REGISTRATION_FORMAT_VERSION = 'suture_lfd.registration', 2


def known_registration(sim: 'Simulation') -> KinematicCorrection | None:
    """Return the registration kept for ``sim`` (:func:`register_arms`), or None."""
    return _REGISTERED.get(sim)


def save_registration(path: str | Path, correction: KinematicCorrection,
                      key: dict[str, Any]) -> None:
    """
    Write a registration to a JSON file (what a dVRK setup keeps between its runs).

    Parameters
    ----------
    path : str or pathlib.Path
        The file (written whole or not at all: a reader never sees a partial file).
    correction : KinematicCorrection
        The registration: per arm its believed base (4x4, ``world``), joint offsets (rad, m),
        base translation (m, ``world``), residual (pixels) and dead bands (rad, m).
    key : dict
        What the registration is valid for (e.g. the robot and the code digest): a load with
        another key finds nothing.

    """
    arms = {arm: {'T_world_base': np.asarray(c.T_world_base, dtype=float).tolist(),
                  'joint_offset': np.asarray(c.joint_offset, dtype=float).tolist(),
                  'translation': np.asarray(c.translation, dtype=float).tolist(),
                  'residual_px': float(c.residual_px),
                  'backlash': np.asarray(c.backlash, dtype=float).tolist()}
            for arm, c in correction.arms.items()}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
    tmp.write_text(json.dumps({'format': REGISTRATION_FORMAT,
                               'version': REGISTRATION_FORMAT_VERSION,
                               'key': key, 'arms': arms}, indent=1))
    os.replace(tmp, path)


def load_registration(path: str | Path, sim: 'Simulation',
                      key: dict[str, Any]) -> KinematicCorrection | None:
    """
    Read a registration saved by :func:`save_registration` and keep it for ``sim``.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.
    sim : sim_bridge.simulation.Simulation
        The robot it registers (its arms' kinematic models); :func:`register_arms` on it then
        returns the loaded registration instead of running one.
    key : dict
        What the registration must be valid for (as saved).

    Returns
    -------
    KinematicCorrection or None
        None when there is no file or it was saved for another key (a registration to run).

    Raises
    ------
    ValueError
        If the file is not a registration (the message names the file and what is wrong).

    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise ValueError(f'{path}: not a readable registration file ({exc})') from exc
    if not isinstance(data, dict) or data.get('format') != REGISTRATION_FORMAT:
        raise ValueError(f"{path}: 'format' must be {REGISTRATION_FORMAT!r}")
    if data.get('version') != REGISTRATION_FORMAT_VERSION or data.get('key') != key:
        return None
    try:
        arms = {arm: ArmCorrection(
            arm=arm, kinematics=sim.kinematics[arm],
            T_world_base=np.array(a['T_world_base'], dtype=float).reshape(4, 4),
            joint_offset=np.array(a['joint_offset'], dtype=float).reshape(6),
            translation=np.array(a['translation'], dtype=float).reshape(3),
            residual_px=float(a['residual_px']),
            backlash=np.array(a['backlash'], dtype=float).reshape(6))
            for arm, a in data['arms'].items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: 'arms' must map PSM names to T_world_base (4x4), "
                         f'joint_offset (6), translation (3), residual_px and backlash (6) '
                         f'({exc!r})') from exc
    correction = KinematicCorrection(arms)
    _REGISTERED[sim] = correction
    return correction


# The registration's poses and instrument model, for a registration stepped by a node's
# controller (suture_lfd.skill.registration_run) instead of run on an in-process simulation.
SPOTS, SIDE, REACH_TIME, RETURN_TIME = _SPOTS, _SIDE, _REACH_TIME, _RETURN_TIME
BENDS, BEND_TIME, BEND_BACK_TIME = _BENDS, _BEND_TIME, _BEND_BACK_TIME
model_points = _model_points
straight_pose = _straight_pose
