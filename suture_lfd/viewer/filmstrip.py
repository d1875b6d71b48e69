"""
Filmstrips: a few frames of a recording from the ECM's point of view, rendered offline.

The scene of the recording's phantom is built in PyBullet (no GUI), and at each chosen time the
PSMs are placed at joint values that reach the recorded tool poses (closed-form inverse
kinematics, each frame starting from the previous solution), the needle at its recorded pose,
and the ECM's left camera renders the frame (recordings do not hold the thread: it is gathered at
the needle's tail).
The frames go side by side, each labelled with its time, into one PNG.
"""

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import PSMS
from suture_lfd.viewer.throw_replay import world_poses

if TYPE_CHECKING:
    from sim_bridge.simulation import Simulation
    from suture_lfd.viewer.replay import Recording

LOG = logging.getLogger(__name__)


def frame_times(recording: 'Recording', n_frames: int = 5) -> list[float]:
    """``n_frames`` times (s) spread over the recording, at its subtask starts when it has them."""
    marks = sorted(t for t, label in recording.marks if 0.0 <= t <= recording.duration)
    if len(marks) >= n_frames - 1:
        times = marks[:n_frames - 1] + [recording.duration]
    else:
        times = list(np.linspace(0.0, recording.duration, n_frames))
    return [float(t) for t in times]


def render_frames(recording: 'Recording', times: list[float], sim: 'Simulation | None' = None
                  ) -> list[Any]:
    """
    Render the ECM's left image of a recording at ``times``.

    Parameters
    ----------
    recording : suture_lfd.viewer.replay.Recording
    times : sequence of float
        Times (s) on the recording's axis.
    sim : sim_bridge.simulation.Simulation, optional
        A simulation of the recording's phantom to draw with (default: one is built).

    Returns
    -------
    list of ndarray
        ``(h, w, 3)`` uint8 images.

    """
    from sim_bridge.simulation import Simulation

    own = sim is None
    if sim is None:
        sim = Simulation(phantom=recording.phantom)
    try:
        sim.reset(0)
        world = sim.world
        q = {arm: sim.arms[arm].measured_jp for arm in PSMS}
        tracks = {track.child: track for track in recording.tracks}
        images = []
        for t in times:
            poses = world_poses(recording, t)
            for arm in PSMS:
                if arm not in poses:
                    continue
                T_base_tool = invert_transform(sim.T_world_base(arm)) @ poses[arm]
                try:
                    q[arm] = sim.kinematics[arm].ik(T_base_tool, q_ref=q[arm])
                except ValueError as exc:  # unreachable: keep the previous configuration
                    LOG.debug('%s at %.2f s: %s', arm, t, exc)
                jaw = None
                jaw_track = tracks.get(f'{arm}_jaw')
                if jaw_track is not None:
                    jaw = float(jaw_track.at(t)[0])
                world.set_arm_joints(arm, q[arm], jaw)
            if 'needle' in poses:
                world.set_needle_pose(poses['needle'])
            needle_tail = (poses.get('needle', sim.needle_pose()) @ [-0.01, 0.0, 0.0, 1.0])[:3]
            world.set_thread_points(np.repeat(needle_tail[None], sim.thread.nodes.shape[0], 0))
            T_camera = poses.get('ECM', sim.camera_pose())
            images.append(sim.camera.render(T_camera).left_rgb)
        return images
    finally:
        if own:
            sim.close()


def write_filmstrip(recording: 'Recording', path: str | Path, title: str = '', n_frames: int = 5,
                    sim: 'Simulation | None' = None) -> list[float]:
    """
    Write a filmstrip PNG of a recording (``n_frames`` ECM frames side by side).

    Returns
    -------
    list of float
        The frames' times (s).

    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    times = frame_times(recording, n_frames)
    images = render_frames(recording, times, sim=sim)
    labels = {round(t, 6): label for t, label in recording.marks}
    fig, axes = plt.subplots(1, len(images), figsize=(2.2 * len(images), 2.2))
    for ax, t, image in zip(np.atleast_1d(axes), times, images):
        ax.imshow(image)
        mark = labels.get(round(t, 6))
        note = '' if not mark else f' ({mark})' if mark == 'end' else f' ({mark} starts)'
        ax.set_title(f'{t:.1f} s{note}', fontsize=7)
        ax.axis('off')
    if title:
        fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return times
