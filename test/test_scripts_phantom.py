"""The scripts' --phantom: a user's mesh reaches the simulator, bad phantoms are named at once."""

import os
from pathlib import Path
import signal
import subprocess
import time

import trimesh

SCRIPTS = Path(__file__).resolve().parent.parent / 'scripts'


def _env(tmp_path):
    return {**os.environ, 'LOG_DIR': str(tmp_path), 'ROS_DOMAIN_ID': os.environ['ROS_DOMAIN_ID']}


def test_the_simulator_script_passes_a_user_mesh_and_says_where_its_markers_are(tmp_path):
    pad = trimesh.creation.box(extents=(0.080, 0.060, 0.010))
    pad.apply_translation([0.10, 0.05, 0.005])  # a scan's own frame: not at the origin
    pad.export(tmp_path / 'my pad.stl')
    proc = subprocess.Popen([str(SCRIPTS / 'simulator.sh'), '--phantom', 'my pad.stl'],
                            cwd=tmp_path, env=_env(tmp_path), stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        log = tmp_path / 'simulator.log'
        deadline = time.monotonic() + 180
        while (not log.exists() or 'simulating' not in log.read_text()) \
                and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        text = log.read_text()
        assert 'pairs mesh1, mesh2, mesh3, mesh4' in text, text[-2000:]
        # the log says where on the file's mesh the markers are
        assert 'on the top surface of my pad.stl, along its longest flat-enough line' in text
        assert 'surface at z = 10.0 mm' in text
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def test_a_pair_of_a_user_mesh_needs_its_phantom_and_a_missing_file_is_named(tmp_path):
    segments = tmp_path / 'seg.npz'
    segments.write_bytes(b'')
    t0 = time.monotonic()
    out = subprocess.run([str(SCRIPTS / 'learn_and_execute.sh'), str(segments), 'mesh1'],
                         env=_env(tmp_path), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and 'give the phantom it is on with --phantom' in out.stderr
    out = subprocess.run([str(SCRIPTS / 'simulator.sh'), '--phantom', 'nowhere.obj'],
                         env=_env(tmp_path), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and 'phantom file nowhere.obj does not exist' in out.stderr
    assert time.monotonic() - t0 < 30


def test_a_scene_file_of_ones_own_reaches_the_simulator(tmp_path):
    trimesh.creation.box(extents=(0.060, 0.040, 0.008)).export(tmp_path / 'pad.stl')
    text = (SCRIPTS.parent / 'config' / 'scene.yaml').read_text()
    text = text.replace('phantoms:\n', 'phantoms:\n  mypad:\n    kind: mesh\n    mesh: pad.stl\n'
                        '    frame: wound\n    marker_prefix: mine\n    wound: {line: []}\n', 1)
    (tmp_path / 'my_scene.yaml').write_text(text)
    proc = subprocess.Popen([str(SCRIPTS / 'simulator.sh'), '--scene', 'my_scene.yaml',
                             '--phantom', 'mypad'], cwd=tmp_path, env=_env(tmp_path),
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        log = tmp_path / 'simulator.log'
        deadline = time.monotonic() + 180
        while (not log.exists() or 'simulating' not in log.read_text()) \
                and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        text = log.read_text()
        assert 'pairs mine1, mine2, mine3, mine4' in text, text[-2000:]
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)
