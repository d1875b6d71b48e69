"""
Suture frames of entry/exit pairs, transfer of needle poses between pairs, and grasp transforms.

A throw is learnt on the **needle** pose. To execute it on another entry/exit pair, its start
and goal poses are carried rigidly from the demonstrated pair's suture frame to the new pair's
frame; to drive an arm, the needle trajectory is turned into a tool trajectory through the
measured grasp ``T_tool_needle``, so a different grasp does not change the learnt skill.

Suture frame (``T_world_suture``): origin at the midpoint of entry and exit; z along the
surface normal (out of the tissue); x from entry towards exit, projected onto the plane
normal to z; y = z x x. Frames and poses follow :mod:`sim_bridge.common.geometry`: 4x4
``T_a_b`` maps frame-b coordinates into frame a; 7-vector poses ``(x, y, z, qx, qy, qz, qw)``;
metres.
"""

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import (
    compose_poses,
    invert_transform,
    pose_from_transform,
    transform_from_pose,
)
from sim_bridge.common.validation import check_array


def suture_frame(entry: ArrayLike, exit: ArrayLike, normal: ArrayLike) -> np.ndarray:
    """
    Return the suture frame ``T_world_suture`` of an entry/exit pair.

    Parameters
    ----------
    entry, exit : array_like, shape (3,)
        Entry and exit points, m (world).
    normal : array_like, shape (3,)
        Tissue surface normal at the pair, pointing out of the tissue (world; any length).

    Returns
    -------
    ndarray, shape (4, 4)
        ``T_world_suture``.

    Raises
    ------
    ValueError
        If the normal is zero or the entry-to-exit direction is (nearly) along the normal.

    """
    entry = check_array(entry, 'entry', shape=(3,))
    exit = check_array(exit, 'exit', shape=(3,))
    normal = check_array(normal, 'normal', shape=(3,))
    length = np.linalg.norm(normal)
    if length < 1e-12:
        raise ValueError('normal must be a non-zero vector (the surface normal at the pair)')
    z = normal / length
    across = (exit - entry) - np.dot(exit - entry, z) * z
    width = np.linalg.norm(across)
    if width < 1e-9:
        raise ValueError('entry and exit must be apart across the surface (their difference '
                         f'is {np.linalg.norm(exit - entry) * 1e3:.3g} mm along the normal)')
    x = across / width
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = 0.5 * (entry + exit)
    return T


def _check_poses(poses: ArrayLike, name: str) -> tuple[np.ndarray, bool]:
    """Return (array, is_vector) for 7-vector poses (..., 7) or 4x4 transforms (..., 4, 4)."""
    poses = check_array(poses, name)
    if poses.ndim >= 1 and poses.shape[-1] == 7:
        transform_from_pose(poses)  # validates the quaternions
        return poses, True
    if poses.ndim >= 2 and poses.shape[-2:] == (4, 4):
        return poses, False
    raise ValueError(f'{name} must be 7-vector poses (..., 7) or 4x4 transforms (..., 4, 4), '
                     f'got shape {poses.shape}')


def _left(T_left: np.ndarray, poses: ArrayLike, name: str) -> np.ndarray:
    """Return ``T_left * poses`` in the layout of ``poses`` (quaternion signs kept)."""
    poses, is_vector = _check_poses(poses, name)
    if is_vector:
        return compose_poses(pose_from_transform(T_left), poses)
    return T_left @ poses


def _right(poses: ArrayLike, T_right: np.ndarray, name: str) -> np.ndarray:
    """Return ``poses * T_right`` in the layout of ``poses`` (quaternion signs kept)."""
    poses, is_vector = _check_poses(poses, name)
    if is_vector:
        return compose_poses(poses, pose_from_transform(T_right))
    return poses @ T_right


def _check_frame(T: ArrayLike, name: str) -> np.ndarray:
    T = check_array(T, name, shape=(4, 4))
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f'{name} must be a rigid 4x4 transform (orthonormal rotation, last row '
                         '0 0 0 1)')
    return T


def transfer_pose(poses: ArrayLike, T_world_from: ArrayLike, T_world_to: ArrayLike) -> np.ndarray:
    """
    Carry world poses from one suture frame to another: ``T_to T_from^-1 T_pose``.

    A pose with coordinates ``c`` in the demonstrated pair's frame gets the same coordinates
    in the new pair's frame.

    Parameters
    ----------
    poses : array_like, shape (..., 7) or (..., 4, 4)
        World poses on the demonstrated pair (needle start/goal, or a whole trajectory).
    T_world_from : array_like, shape (4, 4)
        Suture frame of the demonstrated pair.
    T_world_to : array_like, shape (4, 4)
        Suture frame of the new pair.

    Returns
    -------
    ndarray
        World poses on the new pair, in the layout of ``poses`` (7-vector quaternions keep
        their sign continuity).

    """
    change = _check_frame(T_world_to, 'T_world_to') @ invert_transform(
        _check_frame(T_world_from, 'T_world_from'))
    return _left(change, poses, 'poses')


def throw_start_goal(start: ArrayLike, goal: ArrayLike, T_world_from: ArrayLike,
                     T_world_to: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the needle start and goal poses of a throw on a new pair from a demonstrated one.

    Parameters
    ----------
    start, goal : array_like, shape (7,) or (4, 4)
        Demonstrated needle start and goal poses (world).
    T_world_from, T_world_to : array_like, shape (4, 4)
        Suture frames of the demonstrated and the new pair.

    Returns
    -------
    start_new, goal_new : ndarray
        World poses on the new pair, in the layout of the inputs.

    """
    return (transfer_pose(start, T_world_from, T_world_to),
            transfer_pose(goal, T_world_from, T_world_to))


def poses_in_frame(T_world_frame: ArrayLike, poses: ArrayLike) -> np.ndarray:
    """
    Express world poses in another frame: ``T_frame_pose = T_world_frame^-1 T_world_pose``.

    Learning a throw in its pair's suture frame keeps the per-axis DMP scaling meaningful when
    the throw is executed on a pair with another orientation.

    Parameters
    ----------
    T_world_frame : array_like, shape (4, 4)
        The frame (e.g. a suture frame).
    poses : array_like, shape (..., 7) or (..., 4, 4)
        World poses.

    Returns
    -------
    ndarray
        Poses in the frame, in the layout of ``poses``.

    """
    return _left(invert_transform(_check_frame(T_world_frame, 'T_world_frame')), poses, 'poses')


def poses_from_frame(T_world_frame: ArrayLike, poses: ArrayLike) -> np.ndarray:
    """
    Express poses given in a frame in world coordinates: ``T_world_frame T_frame_pose``.

    Parameters
    ----------
    T_world_frame : array_like, shape (4, 4)
        The frame.
    poses : array_like, shape (..., 7) or (..., 4, 4)
        Poses in the frame.

    Returns
    -------
    ndarray
        World poses, in the layout of ``poses``.

    """
    return _left(_check_frame(T_world_frame, 'T_world_frame'), poses, 'poses')


def grasp_transform(tool_pose: ArrayLike, needle_pose: ArrayLike) -> np.ndarray:
    """
    Return the grasp ``T_tool_needle = T_world_tool^-1 T_world_needle``.

    Parameters
    ----------
    tool_pose, needle_pose : array_like, shape (7,) or (4, 4)
        World poses of the tool tip and the needle at the same instant.

    Returns
    -------
    ndarray, shape (4, 4)
        The needle in the tool frame.

    """
    tool, tool_is_vector = _check_poses(tool_pose, 'tool_pose')
    needle, needle_is_vector = _check_poses(needle_pose, 'needle_pose')
    T_world_tool = transform_from_pose(tool) if tool_is_vector else tool
    T_world_needle = transform_from_pose(needle) if needle_is_vector else needle
    if T_world_tool.shape != (4, 4) or T_world_needle.shape != (4, 4):
        raise ValueError('tool_pose and needle_pose must each be a single pose')
    return invert_transform(T_world_tool) @ T_world_needle


def tool_from_needle_trajectory(needle_poses: ArrayLike, T_tool_needle: ArrayLike) -> np.ndarray:
    """
    Return the tool trajectory that carries the needle along ``needle_poses``.

    ``T_world_tool = T_world_needle T_tool_needle^-1`` for every sample.

    Parameters
    ----------
    needle_poses : array_like, shape (n, 7) or (n, 4, 4)
        Needle poses (world), e.g. a DMP rollout.
    T_tool_needle : array_like, shape (4, 4)
        Grasp (from :func:`grasp_transform`).

    Returns
    -------
    ndarray
        Tool poses (world), in the layout of ``needle_poses``.

    """
    grasp = _check_frame(T_tool_needle, 'T_tool_needle')
    return _right(needle_poses, invert_transform(grasp), 'needle_poses')


def needle_from_tool_trajectory(tool_poses: ArrayLike, T_tool_needle: ArrayLike) -> np.ndarray:
    """
    Return the needle trajectory carried by a tool.

    ``T_world_needle = T_world_tool T_tool_needle`` for every sample.

    Parameters
    ----------
    tool_poses : array_like, shape (n, 7) or (n, 4, 4)
        Tool poses (world).
    T_tool_needle : array_like, shape (4, 4)
        Grasp.

    Returns
    -------
    ndarray
        Needle poses (world), in the layout of ``tool_poses``.

    """
    return _right(tool_poses, _check_frame(T_tool_needle, 'T_tool_needle'), 'tool_poses')
