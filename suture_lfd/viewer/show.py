"""``suture-lfd view``: serve a recording (a bag, or a study's throw) in the viewer's page."""

from pathlib import Path
import time

from suture_lfd.viewer.assets import load_phantom, needle_arc
from suture_lfd.viewer.page import DEFAULT_HOST, DEFAULT_PORT, ViewerPage
from suture_lfd.viewer.replay import ReplayPanel, recording_from_bag
from suture_lfd.viewer.throw_replay import recording_from_throw


def open_replay(path: str | Path, throw: str | None = None, segments: str | Path | None = None,
                host: str = DEFAULT_HOST, port: int = DEFAULT_PORT
                ) -> tuple[ViewerPage, ReplayPanel]:
    """
    Build the page of a recording.

    Parameters
    ----------
    path : str or Path
        Bag directory, or a study folder when ``throw`` is given.
    throw : str, optional
        Row of the study's ``throws.csv`` (1 = first) or a throw key.
    segments : str or Path, optional
        Segment file of a bag (default: found beside it).
    host, port
        Where the page listens.

    Returns
    -------
    page : ViewerPage
    panel : ReplayPanel

    """
    if throw is not None:
        recording = recording_from_throw(path, throw)
    else:
        recording = recording_from_bag(path, segments=segments)
    points, diameter = needle_arc()
    page = ViewerPage(points, diameter, host=host, port=port,
                      title=f'suture_lfd replay: {recording.source}')
    page.show_phantom(load_phantom(recording.phantom))
    panel = page.add_panel(ReplayPanel(recording))
    return page, panel


def serve_recording(path: str | Path, throw: str | None = None,
                    segments: str | Path | None = None, host: str = DEFAULT_HOST,
                    port: int = DEFAULT_PORT, speed: float = 1.0, play: bool = False,
                    seconds: float | None = None) -> int:
    """Serve a recording's page until Ctrl-C (or ``seconds``); return the exit code."""
    page, panel = open_replay(path, throw=throw, segments=segments, host=host, port=port)
    panel.set_speed(speed)
    if play:
        panel.play()
    print(f'suture-lfd view: open {page.url} ({panel.recording.duration:.2f} s recorded)',
          flush=True)
    deadline = None if seconds is None else time.monotonic() + seconds
    try:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        panel.close()
        page.close()
    return 0
