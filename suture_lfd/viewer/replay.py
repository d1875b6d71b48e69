"""
Replay in the viewer's page: recordings of a bag or of a study's throw, and the time slider.

A :class:`Recording` holds what the scene needs over time: pose tracks (``parent -> child``
transforms sampled at their message stamps; between samples the latest one holds, exactly what
was recorded), static transforms, scene events and subtask boundaries, on one time axis (s from
the first sample). :func:`recording_from_bag` reads our bags (the recorder's topics, the
simulator's frames); :func:`recording_from_throw` reads the replay file a study writes per
throw (:mod:`suture_lfd.viewer.throw_replay`). :class:`ReplayPanel` is the page panel: a time
slider (subtask boundaries marked), play/pause and speed.
"""

from dataclasses import dataclass, field
import json
from pathlib import Path
import threading
import time
from typing import Any

import numpy as np
from sim_bridge.common import cdr
from sim_bridge.common.geometry import transform_from_pose
from sim_bridge.common.validation import check_positive
from sim_bridge.common.vocabulary import ARMS, SUBTASKS
from suture_lfd import bags
from suture_lfd.demos.segment_file import SegmentFile
from suture_lfd.viewer.assets import phantom_of_pair

SPEEDS = ('0.25', '0.5', '1', '2', '4', '8')
PLAY_PERIOD = 1.0 / 30.0  # s of wall time between replay frames


@dataclass(frozen=True)
class Track:
    """
    A moving frame: ``T_parent_child`` at times ``t``.

    Attributes
    ----------
    parent, child : str
        Frame names.
    t : ndarray, shape (n,)
        Sample times (s, non-decreasing, on the recording's axis).
    poses : ndarray, shape (n, 7)
        ``(x, y, z, qx, qy, qz, qw)`` (m).

    """

    parent: str
    child: str
    t: np.ndarray
    poses: np.ndarray

    def index(self, t: float) -> int:
        """Index of the latest sample at or before ``t`` (the first one before the start)."""
        return max(int(np.searchsorted(self.t, t, side='right')) - 1, 0)

    def at(self, t: float) -> np.ndarray:
        """Pose ``(7,)`` recorded at time ``t`` (latest sample at or before it)."""
        return self.poses[self.index(t)]


@dataclass
class Recording:
    """
    Everything the scene shows over a recorded span.

    Attributes
    ----------
    tracks : list of Track
    statics : list of tuple
        ``(parent, child, T (4, 4))`` transforms that do not move.
    events : list of tuple
        ``(t s, event dict)``, ordered by time.
    duration : float
        Seconds from the first sample to the last.
    phantom : str
        Phantom the recording was made on (``synthetic``, ``scanned``).
    marks : list of tuple
        ``(t s, label)``: subtask boundaries for the slider.
    source : str
        What was read.

    """

    tracks: list[Track]
    statics: list[tuple[str, str, np.ndarray]]
    events: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    duration: float = 0.0
    phantom: str = 'synthetic'
    marks: list[tuple[float, str]] = field(default_factory=list)
    source: str = ''

    def track(self, child: str) -> Track:
        """Return the track of frame ``child``."""
        for track in self.tracks:
            if track.child == child:
                return track
        raise KeyError(f'{self.source}: no track of frame {child!r}; tracks: '
                       f'{[t.child for t in self.tracks]}')

    def apply(self, scene: Any, t: float, statics: bool = True) -> None:
        """Pose ``scene`` (a SceneView) as recorded at time ``t`` (s)."""
        if statics:
            for parent, child, T in self.statics:
                scene.set_transform(parent, child, T)
        for track in self.tracks:
            scene.set_transform(track.parent, track.child, transform_from_pose(track.at(t)))

    def events_until(self, t: float) -> list[tuple[float, dict[str, Any]]]:
        """Events at or before ``t``."""
        return [(s, e) for s, e in self.events if s <= t + 1e-9]


def _pose_topics(topics: Any) -> dict[str, tuple[str, str, str]]:
    """Map a bag's pose topics to ``(kind, parent default, child)``."""
    out: dict[str, tuple[str, str, str]] = {}
    for topic in topics:
        parts = topic.strip('/').split('/')
        if topic == '/sim/needle/measured_cp':
            out[topic] = ('track', 'world', 'needle')
        elif len(parts) == 2 and parts[0] in ARMS and parts[1] == 'measured_cp':
            out[topic] = ('track', f'{parts[0]}_base', parts[0])
        elif len(parts) == 3 and parts[0] == 'sim' and parts[2] == 'base_frame':
            out[topic] = ('static', 'world', f'{parts[1]}_base')
        elif len(parts) == 4 and parts[:2] == ['sim', 'markers']:
            out[topic] = ('static', 'world', f'{parts[2]}_{parts[3]}')
        elif topic == '/sim/phantom/measured_cp':
            out[topic] = ('static', 'world', 'phantom')
    return out


def default_segments(bag: str | Path) -> Path | None:
    """Return the segment file of a bag where the package puts it, or None."""
    folder = Path(bag)
    for candidate in (folder.parent / f'{folder.name}.segments.npz',
                      folder.parent.parent / 'segments' / f'{folder.name}.npz'):
        if candidate.is_file():
            return candidate
    return None


def recording_from_bag(path: str | Path, segments: str | Path | None = None) -> Recording:
    """
    Read a bag into a :class:`Recording`.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory with (at least) ``/sim/needle/measured_cp``.
    segments : str or Path, optional
        Segment file whose subtask boundaries are marked; default :func:`default_segments`.

    Raises
    ------
    suture_lfd.bags.BagError
        If the bag cannot be read or has no needle pose.

    """
    path = Path(path)
    samples: dict[tuple[str, str], list[tuple[float, Any]]] = {}
    statics: dict[str, tuple[str, np.ndarray]] = {}
    events: list[tuple[float, dict[str, Any]]] = []
    with bags.open_bag(path, required=('/sim/needle/measured_cp',)) as reader:
        topics = _pose_topics(reader.topics)
        wanted = [*topics, '/sim/events', '/tf_static']
        for message in reader.messages([t for t in wanted if t in reader.topics]):
            if message.topic in topics:
                kind, parent, child = topics[message.topic]
                got = cdr.pose_stamped_fields(message.rawdata)
                if got is None:
                    msg = reader.deserialize(message)
                    p, q = msg.pose.position, msg.pose.orientation
                    got = (msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                           msg.header.frame_id, (p.x, p.y, p.z, q.x, q.y, q.z, q.w))
                stamp, frame, pose = got
                parent = frame or parent
                if kind == 'static':
                    statics[child] = (parent, transform_from_pose(pose))
                else:
                    samples.setdefault((parent, child), []).append((stamp, pose))
            elif message.topic == '/sim/events':
                msg = reader.deserialize(message)
                try:
                    data = json.loads(msg.string)
                except json.JSONDecodeError:
                    continue
                if isinstance(data, dict) and 'kind' in data:
                    events.append((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                                   data))
            else:
                for tr in reader.deserialize(message).transforms:
                    t, q = tr.transform.translation, tr.transform.rotation
                    statics.setdefault(tr.child_frame_id, (
                        tr.header.frame_id,
                        transform_from_pose((t.x, t.y, t.z, q.x, q.y, q.z, q.w))))
    t0 = min(s[0][0] for s in samples.values())
    t1 = max(s[-1][0] for s in samples.values())
    tracks: list[Track] = []
    for (parent, child), rows in sorted(samples.items()):
        rows.sort(key=lambda r: r[0])
        tracks.append(Track(parent, child, np.array([r[0] for r in rows]) - t0,
                            np.array([r[1] for r in rows], dtype=float)))
    pairs = sorted(c.rsplit('_', 1)[0] for c in statics if c.endswith('_entry'))
    marks: list[tuple[float, str]] = []
    segment_file = default_segments(path) if segments is None else Path(segments)
    if segment_file is not None:
        seg = SegmentFile.load(segment_file)
        marks = [(float(start) - t0, name) for name, (start, _) in
                 zip(SUBTASKS, seg.subtask_times)]
        marks.append((float(seg.subtask_times[-1, 1]) - t0, 'end'))
    return Recording(
        tracks=tracks, statics=[(p, c, T) for c, (p, T) in statics.items()],
        events=sorted(((t - t0, e) for t, e in events), key=lambda r: r[0]),
        duration=float(t1 - t0), phantom=phantom_of_pair(pairs[0]) if pairs else 'synthetic',
        marks=marks, source=str(path))


class ReplayPanel:
    """
    The replay controls of a page: time slider, play/pause, speed.

    Parameters
    ----------
    recording : Recording

    Attributes
    ----------
    time : float
        Time shown (s).
    playing : bool
    speed : float
    finished : threading.Event
        Set when playing reaches the end of the recording.
    marks : tuple
        ``(t, label)`` marked on the slider (the recording's subtask boundaries).

    """

    def __init__(self, recording: Recording) -> None:
        self.recording = recording
        self.time = 0.0
        self.playing = False
        self.speed = 1.0
        self.finished = threading.Event()
        self._lock = threading.RLock()
        self._page: Any = None
        self._events_shown = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._setting = False  # the slider is being moved by seek(), not by a person
        self._t_wall = 0.0
        self._t_start = 0.0
        self.marks: tuple[tuple[float, str], ...] = ()
        self.slider: Any = None
        self.play_button: Any = None
        self.speed_menu: Any = None

    def attach(self, page: Any) -> None:
        """Build the controls on ``page`` and show time 0."""
        self._page = page
        gui = page.server.gui
        rec = self.recording
        with gui.add_folder('Replay'):
            gui.add_markdown(f'`{Path(rec.source).name}`: {rec.duration:.2f} s')
            self.marks = tuple((round(t, 2), label) for t, label in rec.marks
                               if 0.0 <= t <= rec.duration)
            self.slider = gui.add_slider('time (s)', min=0.0, max=max(rec.duration, 0.01),
                                         step=0.01, initial_value=0.0, marks=self.marks or None)
            self.play_button = gui.add_button('Play')
            self.speed_menu = gui.add_dropdown('speed', SPEEDS, initial_value='1')
        self.slider.on_update(lambda _e: self._on_slider())
        self.play_button.on_click(lambda _e: self.toggle())
        self.speed_menu.on_update(lambda _e: self.set_speed(float(self.speed_menu.value)))
        rec.apply(page.scene, 0.0)
        self._show(0.0)
        self._thread = threading.Thread(target=self._run, daemon=True, name='replay')
        self._thread.start()

    # --- controls ------------------------------------------------------------------------------

    def seek(self, t: float) -> None:
        """Show time ``t`` (s, clipped to the recording)."""
        t = min(max(float(t), 0.0), self.recording.duration)
        with self._lock:
            self._show(t)
            if abs(float(self.slider.value) - t) > 0.005:
                self._setting = True
                self.slider.value = round(t, 2)

    def play(self, speed: float | None = None) -> None:
        """Play from the current time (from the start if at the end)."""
        with self._lock:
            if speed is not None:
                self.set_speed(speed)
            if self.time >= self.recording.duration:
                self._show(0.0)
            self.finished.clear()
            self._t_wall = time.monotonic()
            self._t_start = self.time
            self.playing = True
            self.play_button.label = 'Pause'

    def pause(self) -> None:
        with self._lock:
            self.playing = False
            self.play_button.label = 'Play'

    def toggle(self) -> None:
        """Play or pause (the button)."""
        if self.playing:
            self.pause()
        else:
            self.play()

    def set_speed(self, speed: float) -> None:
        """Replay speed (recorded seconds per wall second, > 0)."""
        value = check_positive(speed, 'replay speed')
        with self._lock:
            if self.playing:
                self._t_wall = time.monotonic()
                self._t_start = self.time
            self.speed = value
            label = f'{value:g}'
            if label in SPEEDS and self.speed_menu.value != label:
                self.speed_menu.value = label

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    # --- internals -----------------------------------------------------------------------------

    def _on_slider(self) -> None:
        with self._lock:
            if self._setting:
                self._setting = False
                return
            if self.playing:
                self._t_wall = time.monotonic()
                self._t_start = float(self.slider.value)
            self._show(float(self.slider.value))

    def _show(self, t: float) -> None:
        rec = self.recording
        page = self._page
        rec.apply(page.scene, t, statics=False)
        shown = rec.events_until(t)
        if len(shown) < self._events_shown:
            page.clear_events()
            self._events_shown = 0
        for s, event in shown[self._events_shown:]:
            page.add_event(s, event)
        self._events_shown = len(shown)
        self.time = t
        page.render()

    def _run(self) -> None:
        while not self._stop.wait(PLAY_PERIOD):
            with self._lock:
                if not self.playing:
                    continue
                t = self._t_start + (time.monotonic() - self._t_wall) * self.speed
                end = t >= self.recording.duration
                if end:
                    t = self.recording.duration
                    self.playing = False
                    self.play_button.label = 'Play'
                self.seek(t)
                if end:  # after the seek: a waiter sees the last frame's time
                    self.finished.set()
