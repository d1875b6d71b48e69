"""
The grasp: where the needle sits in the holding jaw, from a few frames of perception.

A grasp, regrasp or handover fixes the needle in the jaw; its pose there, ``T_tool_needle``, is
what turns the tool pose the arm reports into the needle's pose while it is held (the prior of
:meth:`suture_lfd.perception.needle.NeedleTracker.estimate`). It is estimated once after each
grasp from a few frames: per frame the tool pose (the arm's kinematics carried into the camera
frame) and the needle's estimate, ``T_tool_needle = inv(T_camera_tool) T_camera_needle``, averaged
(positions: the mean; rotations: the chordal L2 mean of
:meth:`scipy.spatial.transform.Rotation.mean`) over the frames whose estimate was found, each
weighted by ``1 / (residual_px + 0.1)``.

Seen nearly face on, one pair leaves the needle's tilt across the line of sight open;
:meth:`suture_lfd.perception.needle.NeedleTracker.fit_grasp` fits one grasp to the edges of
several pairs at once (:class:`HeldView`: the images and the holding tool's pose), among them the
pair of the needle lying where the jaw then closed on it (:class:`GraspFit`).

Frames: camera = the left optical frame; tool = the PSM tool-tip frame (``measured_cp``'s); metres.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

if TYPE_CHECKING:
    from suture_lfd.perception.needle import NeedleEstimate


@dataclass(frozen=True, eq=False)
class GraspEstimate:
    """
    The needle's pose in the holding jaw.

    Attributes
    ----------
    T_tool_needle : ndarray, shape (4, 4)
        Needle frame in the tool-tip frame (m).
    spread_position : float
        RMS distance (m) of the frames' needle origins from the mean.
    spread_angle : float
        RMS angle (rad) of the frames' needle orientations from the mean.
    n_frames : int
        Frames that were used (estimates found).

    """

    T_tool_needle: np.ndarray
    spread_position: float
    spread_angle: float
    n_frames: int


@dataclass(frozen=True, eq=False)
class HeldView:
    """
    One stereo pair of a grasp, for :meth:`~suture_lfd.perception.needle.NeedleTracker.fit_grasp`.

    Attributes
    ----------
    left, right : ndarray, shape (height, width, 3), uint8
        The rectified RGB pair.
    T_camera_tool : ndarray, shape (4, 4)
        The holding tool's pose (camera frame) -- for a pair taken before the grasp, where the
        tool closed its jaw on the needle.
    tools : tuple of ndarray (4, 4)
        Poses (camera frame) of the instruments in view when the pair was taken: where their
        jaws, wrist or shaft cover the arc it is not looked for.
    tool_at : callable, optional
        ``tool_at(offsets) -> T_camera_tool``: the holding tool's pose had its arm's wrist
        joints ``offsets`` (rad) more than believed (``tool_at(0)`` is ``T_camera_tool``); given,
        :meth:`~suture_lfd.perception.needle.NeedleTracker.fit_grasp` can fit those offsets,
        shared by every pair, with the grasp.

    """

    left: np.ndarray
    right: np.ndarray
    T_camera_tool: np.ndarray
    tools: tuple = ()
    tool_at: 'Callable[[np.ndarray], np.ndarray] | None' = None


@dataclass(frozen=True, eq=False)
class GraspFit:
    """
    A grasp fitted to several pairs at once.

    Attributes
    ----------
    T_tool_needle : ndarray, shape (4, 4)
        The grasp (m).
    residual_px : tuple of float
        Per pair, the RMS distance (pixels) of the arc points seen in both images from the
        needle's centre line (``inf`` when none is seen).
    visible_share : tuple of float
        Per pair, the share of the arc seen in both images.
    offsets : ndarray, shape (k,)
        The wrist offsets (rad) fitted with the grasp (empty when none were fitted).

    """

    T_tool_needle: np.ndarray
    residual_px: tuple
    visible_share: tuple
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))


def estimate_grasp(tool_poses: Sequence[ArrayLike],
                   estimates: Sequence['NeedleEstimate']) -> GraspEstimate:
    """
    Estimate the grasp ``T_tool_needle`` from a few frames of one grasp.

    Parameters
    ----------
    tool_poses : sequence of array_like, shape (4, 4)
        Tool-tip pose of the holding arm per frame, in the camera frame.
    estimates : sequence of suture_lfd.perception.needle.NeedleEstimate
        The needle's estimate of the same frames.

    Returns
    -------
    GraspEstimate

    Raises
    ------
    ValueError
        When the lengths differ or no frame has a found estimate.

    """
    tool_poses = list(tool_poses)
    estimates = list(estimates)
    if len(tool_poses) != len(estimates):
        raise ValueError(f'estimate_grasp needs one tool pose per estimate, got '
                         f'{len(tool_poses)} and {len(estimates)}')
    grasps, weights = [], []
    for pose, est in zip(tool_poses, estimates):
        if not est.found or est.pose_camera is None:
            continue
        T_tool = np.asarray(pose, dtype=float)
        if T_tool.shape != (4, 4):
            raise ValueError(f'tool pose must be 4x4, got shape {T_tool.shape}')
        R = T_tool[:3, :3]
        T = np.eye(4)
        T[:3, :3] = R.T @ est.pose_camera[:3, :3]
        T[:3, 3] = R.T @ (est.pose_camera[:3, 3] - T_tool[:3, 3])
        grasps.append(T)
        weights.append(1.0 / (est.residual_px + 0.1))
    if not grasps:
        raise ValueError(f'estimate_grasp: none of the {len(estimates)} frames has a found '
                         f'needle estimate')
    w = np.asarray(weights) / np.sum(weights)
    positions = np.array([T[:3, 3] for T in grasps])
    rotations = Rotation.from_matrix(np.array([T[:3, :3] for T in grasps]))
    mean_rotation = rotations.mean(weights=w)
    mean_position = w @ positions
    result = np.eye(4)
    result[:3, :3] = mean_rotation.as_matrix()
    result[:3, 3] = mean_position
    spread_p = float(np.sqrt(w @ np.sum((positions - mean_position) ** 2, axis=1)))
    spread_a = float(np.sqrt(w @ (mean_rotation.inv() * rotations).magnitude() ** 2))
    return GraspEstimate(T_tool_needle=result, spread_position=spread_p, spread_angle=spread_a,
                         n_frames=len(grasps))


def needle_prior(T_camera_tool: ArrayLike, grasp: GraspEstimate) -> np.ndarray:
    """
    Return where a held needle should be: ``T_camera_tool @ grasp.T_tool_needle`` (4, 4).

    Parameters
    ----------
    T_camera_tool : array_like, shape (4, 4)
        Tool-tip pose of the holding arm in the camera frame.
    grasp : GraspEstimate

    """
    return np.asarray(T_camera_tool, dtype=float) @ grasp.T_tool_needle
