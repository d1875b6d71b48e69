"""
The camera-to-arm registration as a sequence a controller steps: poses commanded, images taken.

:func:`suture_lfd.skill.arm_registration.register_arms` registers the PSMs of an in-process
simulation by running it; a node has only the arms' reports, its commands and the stereo images
as they come. :class:`RegistrationRun` is the same registration stepped like a controller: at
each :meth:`RegistrationRun.step` it is given the arms' reports and, when there is one, the
newest stereo pair, and returns the command to send. Each PSM in turn goes to the poses of
:mod:`~suture_lfd.skill.arm_registration` (around the centre of the markers seen, wrist
straight, jaw closed; at the last one the wrist bent and straightened again before each look),
waits the reach time there, takes the first stereo pair stamped after that, finds its
instrument near where its kinematics put it
(:func:`suture_lfd.perception.instrument.find_instrument`), and goes back to where it started;
then each arm's correction is fitted (:func:`~suture_lfd.skill.arm_registration.
fit_arm_correction`, with the joints each arm reported on its way to each pose: the dead
bands) and :attr:`RegistrationRun.correction` is set.

It reads only what a dVRK provides: the reported joints (``q``), the believed bases, the
camera's reported pose, the images and their ``camera_info``.

Frames: ``world`` (as the robot believes it), the left optical frame ``camera``; 4x4 poses;
metres, radians, seconds (simulation time, the messages' stamps).
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import logging
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.control import Command, Observation
from suture_lfd.perception.instrument import InstrumentView, find_instrument
from suture_lfd.skill import arm_registration as registration
from suture_lfd.skill.arm_registration import KinematicCorrection, fit_arm_correction

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class StereoLook:
    """
    One stereo pair as it came.

    Attributes
    ----------
    stamp : float
        The images' stamp (s).
    left_rgb, right_rgb : ndarray, shape (h, w, 3), uint8
    T_world_camera : ndarray, shape (4, 4)
        The left optical frame's pose (``world``) as the robot reports it.

    """

    stamp: float
    left_rgb: np.ndarray
    right_rgb: np.ndarray
    T_world_camera: np.ndarray


class RegistrationRun:
    """
    The PSMs' registration against the endoscope, one step at a time.

    Parameters
    ----------
    kinematics : mapping of str to sim_bridge.kinematics.PsmKinematics
        Each PSM's kinematic model.
    stereo : suture_lfd.perception.StereoModel
        The camera model (from the pair's ``camera_info``).
    jaw : tuple of float
        ``(length, width, thickness)`` (m) of the closed jaws.
    centre : array_like, shape (3,)
        Centre (``world``) of the markers seen: the poses are placed around it.
    arms : sequence of str, optional
        The arms registered, in turn (default both PSMs).

    Attributes
    ----------
    done : bool
        Whether every arm was seen and fitted (or given up).
    correction : KinematicCorrection or None
        The trusted fits, once done.
    samples : dict of str to list
        Per arm ``(q, T_camera_world, view_left, view_right)`` per pose.
    paths : dict of str to list
        Per arm and pose, the joints it reported on its way there (``(m, 6)``).

    """

    def __init__(self, kinematics: Mapping[str, Any], stereo: Any,
                 jaw: tuple[float, float, float], centre: ArrayLike,
                 arms: Sequence[str] = PSMS) -> None:
        self.kinematics = dict(kinematics)
        self.stereo = stereo
        self.jaw = tuple(float(v) for v in jaw)
        self.centre = np.asarray(centre, dtype=float).reshape(3)
        self.arms = tuple(arms)
        self.samples: dict[str, list] = {a: [] for a in self.arms}
        self.paths: dict[str, list[np.ndarray]] = {a: [] for a in self.arms}
        self.correction: KinematicCorrection | None = None
        self._arm = 0
        self._spot = 0            # index into the spots, then the bends; past them: going back
        self._bent = False        # a bend visit: the bent pose reached, going straight again
        self._path: list[np.ndarray] = []
        self._start: dict[str, np.ndarray] = {}
        self._bases: dict[str, np.ndarray] = {}
        self._sent_at: float | None = None
        self._target: np.ndarray | None = None

    @property
    def done(self) -> bool:
        """Whether the registration is over (:attr:`correction` set)."""
        return self.correction is not None

    @property
    def arm(self) -> str | None:
        """The arm being registered now (None when done)."""
        return None if self._arm >= len(self.arms) else self.arms[self._arm]

    def step(self, obs: Observation, look: StereoLook | None = None) -> Command:
        """
        Advance the registration and return the command to send now.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            The arms' reports (``t``, ``T_world_tool``, ``q``, ``T_world_base``), uncorrected.
        look : StereoLook, optional
            The newest stereo pair (used once it is stamped after the arm settled).

        Returns
        -------
        sim_bridge.control.Command
            The registered arm's target (``subtask`` ``'registration'``); no target once done.

        """
        if not self._start:
            self._start = {a: np.array(obs.T_world_tool[a]) for a in self.arms}
            self._bases = {a: np.array(obs.T_world_base[a]) for a in self.arms}
        arm = self.arm
        if arm is None:
            return Command(t=obs.t, T_world_tool={}, jaw={}, subtask='registration')
        if obs.q is not None and obs.q.get(arm) is not None:
            self._path.append(np.array(obs.q[arm], dtype=float))
        n_spots, n_bends = len(registration.SPOTS), len(registration.BENDS)
        going_back = self._spot >= n_spots + n_bends
        bending = not going_back and self._spot >= n_spots
        if self._sent_at is None:
            self._sent_at = obs.t
            if going_back:
                self._target = self._start[arm]
            elif bending and not self._bent:
                joint, angle = registration.BENDS[self._spot - n_spots]
                assert obs.q is not None, 'the registration needs the reported joints'
                self._target = registration.bent_pose(
                    self.kinematics[arm], self._bases[arm], self._pose(arm, n_spots - 1),
                    obs.q[arm], joint, angle)
            else:
                self._target = self._pose(arm, min(self._spot, n_spots - 1))
        if going_back:
            wait = registration.RETURN_TIME
        elif bending:
            wait = registration.BEND_BACK_TIME if self._bent else registration.BEND_TIME
        else:
            wait = registration.REACH_TIME[self._spot]
        if obs.t - self._sent_at >= wait:
            if going_back:
                self._next_arm()
            elif bending and not self._bent:
                self._bent = True
                self._sent_at = None
            elif look is not None and look.stamp >= self._sent_at + wait:
                self.samples[arm].append(self._see(arm, obs, look))
                self.paths[arm].append(np.array(self._path))
                self._path = self._path[-1:]
                self._spot += 1
                self._bent = False
                self._sent_at = None
        target = self._target
        return Command(t=obs.t, T_world_tool={arm: target},
                       jaw={} if going_back else {arm: 0.0}, subtask='registration')

    def _pose(self, arm: str, spot: int) -> np.ndarray:
        x, y, z = registration.SPOTS[spot]
        tip = self.centre + np.array([registration.SIDE[arm] * x, y, z])
        return registration.straight_pose(self._bases[arm][:3, 3], tip, self._start[arm])

    def _see(self, arm: str, obs: Observation,
             look: StereoLook) -> tuple[np.ndarray, np.ndarray, InstrumentView | None,
                                        InstrumentView | None]:
        """Find the instrument in both images near where the reported joints put it."""
        assert obs.q is not None, 'the registration needs the reported joints'
        q = np.asarray(obs.q[arm], dtype=float)
        T_cw = invert_transform(look.T_world_camera)
        pts = registration.model_points(self.kinematics[arm], self._bases[arm], q,
                                         np.zeros(6), self.jaw)
        uv_l, uv_r = self.stereo.project(pts @ T_cw[:3, :3].T + T_cw[:3, 3])
        views = [find_instrument(img, uv[:2], uv[2])
                 for img, uv in ((look.left_rgb, uv_l), (look.right_rgb, uv_r))]
        _LOG.debug('%s pose %d seen: %s', arm, self._spot, [v is not None for v in views])
        return q, T_cw, views[0], views[1]

    def _next_arm(self) -> None:
        self._arm += 1
        self._spot = 0
        self._sent_at = None
        self._path = []
        if self._arm >= len(self.arms):
            self.correction = self._fit()

    def _fit(self) -> KinematicCorrection:
        arms = {}
        for arm in self.arms:
            try:
                fit = fit_arm_correction(arm, self.kinematics[arm], self._bases[arm],
                                         self.samples[arm], self.stereo, self.jaw,
                                         self.paths[arm])
            except ValueError as exc:
                _LOG.warning('registration: %s', exc)
                continue
            if fit.residual_px > registration.MAX_RESIDUAL_PX:
                _LOG.warning('registration of %s not trusted: residual %.1f px', arm,
                             fit.residual_px)
                continue
            arms[arm] = fit
        return KinematicCorrection(arms)
