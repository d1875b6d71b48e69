"""
What a study stores of each executed throw so that the viewer can replay it.

A :class:`ThrowSampler` watches the in-process simulation while a throw executes and keeps, at
:data:`SAMPLE_RATE` of simulated time, the needle pose and both PSMs' tool poses (``world``) and
jaw angles; with the scene's fixed frames (arm bases, ECM camera, markers, phantom) and the
throw's events it is saved as ``replays/<method>_<subject>_<train>_<test>.npz`` of the study
folder (compressed; format tag :data:`FORMAT`). :func:`recording_from_throw` reads it back as a
:class:`~suture_lfd.viewer.replay.Recording`.
"""

from collections.abc import Mapping, Sequence
import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.archive import load_archive, save_archive
from sim_bridge.common.geometry import pose_from_transform, transform_from_pose
from sim_bridge.common.vocabulary import ARMS, PSMS
from suture_lfd.viewer.replay import SUBTASKS, Recording, Track

if TYPE_CHECKING:
    from sim_bridge.simulation import Simulation

FORMAT = 'suture_lfd.throw_replay'
FORMAT_VERSION = 2  # 2: the version under the key 'format_version' of every archive
SAMPLE_RATE = 20.0  # Hz of simulated time


def replay_name(job: Mapping[str, Any]) -> str:
    """File name (relative to the study folder) of a throw job's replay."""
    return (f'replays/{job["method"]}_{job["subject"]}_{job["train_pair"]}_'
            f'{job["test_pair"]}.npz')


class ThrowSampler:
    """
    Samples a simulation during a throw (call it with the simulation at every control step).

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
    rate : float
        Samples per second of simulated time.

    """

    def __init__(self, sim: 'Simulation', rate: float = SAMPLE_RATE) -> None:
        self.sim = sim
        self.period = 1.0 / rate
        self._times: list[float] = []
        self._poses: list[tuple[np.ndarray, ...]] = []
        self._jaws: list[list[float]] = []
        self._next = -np.inf

    def __call__(self, sim: 'Simulation | None' = None) -> None:
        if sim is None:
            sim = self.sim
        t = sim.time
        if t + 1e-9 < self._next:
            return
        self._next = t + self.period
        # the 4x4 poses are kept and turned into 7-vectors all at once by the rows
        self._times.append(t)
        self._poses.append((sim.needle_pose(), *(np.array(sim.tool_pose(arm)) for arm in PSMS)))
        self._jaws.append([float(sim.arms[arm].jaw_measured_jp) for arm in PSMS])

    @property
    def rows(self) -> np.ndarray:
        """
        The samples so far, shape (n, 24).

        Columns: ``t`` (s), the needle pose (7), then per PSM its tool pose (7) and jaw (rad);
        poses ``(x, y, z, qx, qy, qz, qw)`` in ``world``.
        """
        n = len(self._times)
        rows = np.empty((n, 1 + 7 + 2 * 8))
        if n:
            poses = pose_from_transform(np.asarray(self._poses, dtype=float))  # (n, 3, 7)
            rows[:, 0] = self._times
            rows[:, 1:8] = poses[:, 0]
            for k in range(len(PSMS)):
                col = 8 + 8 * k
                rows[:, col:col + 7] = poses[:, 1 + k]
                rows[:, col + 7] = [jaw[k] for jaw in self._jaws]
        return rows

    def save(self, path: str | Path, pair: str, events: Sequence[Mapping[str, Any]] = (),
             subtask_times: Mapping[str, tuple[float, float]] | None = None) -> int:
        """
        Write the replay file (atomically) and return its size in bytes.

        Parameters
        ----------
        path : str or Path
        pair : str
            Executed marker pair.
        events : sequence of dict
            The throw's scene events (``{"kind", "t", ...}``, t in simulated s).
        subtask_times : dict, optional
            Subtask -> ``(start, end)`` s.

        """
        sim = self.sim
        rows = self.rows
        bases = np.stack([sim.T_world_base(a) for a in ARMS])
        markers = dict(sim.marker_poses())
        spans = np.full((len(SUBTASKS), 2), np.nan)
        for k, name in enumerate(SUBTASKS):
            if subtask_times and name in subtask_times:
                spans[k] = subtask_times[name]
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_archive(path, {
            'samples': rows.astype(np.float32), 't': rows[:, 0], 'bases': bases,
            'ecm': sim.camera_pose(), 'ecm_left': sim.camera.T_tip_left,
            'phantom_pose': sim.phantom_pose(), 'phantom': np.array(sim.phantom.name),
            'pair': np.array(pair), 'marker_names': np.array(list(markers)),
            'marker_poses': np.stack(list(markers.values())),
            'events': np.array(json.dumps(list(events))), 'subtasks': spans,
        }, FORMAT, FORMAT_VERSION, compressed=True)
        return path.stat().st_size


def _find_row(study: str | Path, throw: str) -> dict[str, str]:
    path = Path(study) / 'throws.csv'
    if not path.is_file():
        raise ValueError(f'{path} does not exist: give the folder of a study (its report)')
    with open(path, newline='') as handle:
        rows = list(csv.DictReader(handle))
    if str(throw).isdigit():
        index = int(throw)
        if not 1 <= index <= len(rows):
            raise ValueError(f'{study}/throws.csv has {len(rows)} throws; --throw must be '
                             f'1 .. {len(rows)}, got {throw}')
        return rows[index - 1]
    parts = str(throw).split('/')
    if len(parts) == 5 and parts[0] == 'throw':
        _, method, subject, train, test = parts
        return {'method': method, 'subject': subject, 'train_pair': train, 'test_pair': test}
    raise ValueError(f'--throw must be a row number of throws.csv or a key '
                     f'throw/<method>/<subject>/<train>/<test>, got {throw!r}')


def recording_from_throw(study: str | Path, throw: str) -> Recording:
    """
    Read the replay of a study's throw.

    Parameters
    ----------
    study : str or Path
        Study folder (holding ``throws.csv`` and ``replays/``).
    throw : str or int
        Row of ``throws.csv`` (1 = the first throw) or ``throw/<method>/<subject>/<train>/<test>``.

    Returns
    -------
    Recording

    """
    row = _find_row(study, throw)
    path = Path(study) / replay_name(row)
    if not path.is_file():
        raise ValueError(f'{path}: no replay of this throw (studies record one per throw since '
                         'the viewer exists; run the study again to make them)')
    return recording_from_file(path)


def recording_from_file(path: str | Path) -> Recording:
    """Read a throw replay file (see :class:`ThrowSampler`) into a Recording."""
    data = load_archive(path, FORMAT, FORMAT_VERSION, 'throw replay')
    rows = np.asarray(data['samples'], float)
    t = np.asarray(data['t'], float)
    t0 = float(t[0]) if len(t) else 0.0
    tracks = [Track('world', 'needle', t - t0, rows[:, 1:8])]
    for k, arm in enumerate(PSMS):
        col = 8 + 8 * k
        tracks.append(Track('world', arm, t - t0, rows[:, col:col + 7]))
    bases = data['bases']
    statics = [('world', f'{arm}_base', bases[k]) for k, arm in
               enumerate(ARMS)]
    statics += [('world', 'ECM', data['ecm']), ('ECM', 'ECM_left_optical', data['ecm_left']),
                ('world', 'phantom', data['phantom_pose'])]
    statics += [('world', name.replace('.', '_'), T)
                for name, T in zip(data['marker_names'], data['marker_poses'])]
    events = sorted(((float(e.get('t', t0)) - t0, e)
                     for e in json.loads(str(data['events']))), key=lambda r: r[0])
    spans = data['subtasks']
    # subtask spans count from the throw's first controller step, the first sample
    marks = [(float(s), name) for name, (s, _) in zip(SUBTASKS, spans) if np.isfinite(s)]
    duration = float(t[-1] - t0) if len(t) else 0.0
    return Recording(tracks=tracks, statics=statics, events=events, duration=duration,
                     phantom=str(data['phantom']), marks=marks, source=str(path))


def world_poses(recording: Recording, t: float,
                frames: Sequence[str] = ('needle', *ARMS)
                ) -> dict[str, np.ndarray]:
    """World poses (4x4) of ``frames`` in a recording at time ``t`` (missing ones left out)."""
    from suture_lfd.viewer.scene import TransformTree

    tree = TransformTree()
    for parent, child, T in recording.statics:
        tree.set(parent, child, T)
    for track in recording.tracks:
        tree.set(track.parent, track.child, transform_from_pose(track.at(t)))
    out: dict[str, np.ndarray] = {}
    for frame in frames:
        T_world_frame = tree.world(frame)
        if T_world_frame is not None:
            out[frame] = T_world_frame
    return out
