"""
A real headless Chromium driven over its DevTools protocol, for the viewer's browser tests.

Debian's ``chromium`` (installed by ``tools/setup.sh``) with software GL (SwiftShader), offline:
the page comes from the viewer on 127.0.0.1. :func:`find_chromium` returns None when no browser
is installed; the tests then skip and say so.
"""

import base64
import io
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request

import numpy as np
from PIL import Image
from websockets.sync.client import connect

FLAGS = ('--headless=new', '--no-sandbox', '--use-angle=swiftshader',
         '--enable-unsafe-swiftshader', '--no-first-run', '--no-default-browser-check',
         '--disable-gpu-sandbox', '--disable-extensions', '--disable-background-networking',
         '--disable-renderer-backgrounding', '--disable-background-timer-throttling',
         '--disable-backgrounding-occluded-windows', '--hide-scrollbars', '--mute-audio')


def find_chromium():
    """Path of a Chromium executable, or None."""
    for name in ('chromium', 'chromium-browser', 'google-chrome'):
        path = shutil.which(name)
        if path:
            return path
    return None


class Chromium:
    """
    One headless Chromium with one page, driven over the DevTools protocol (CDP).

    Parameters
    ----------
    executable : str
        Chromium binary.
    width, height : int
        Window size (px); screenshots have this size.

    """

    def __init__(self, executable, width=960, height=600):
        self.width, self.height = width, height
        self._profile = tempfile.TemporaryDirectory(prefix='viewer-chromium-')
        self.proc = subprocess.Popen(
            [executable, *FLAGS, f'--window-size={width},{height}',
             f'--user-data-dir={self._profile.name}', '--remote-debugging-port=0',
             'about:blank'],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        port = self._devtools_port()
        targets = json.load(urllib.request.urlopen(f'http://127.0.0.1:{port}/json', timeout=10))
        page = next(t for t in targets if t.get('type') == 'page')
        self.ws = connect(page['webSocketDebuggerUrl'], max_size=None, open_timeout=20)
        self._id = 0
        self.send('Page.enable')
        self.send('Runtime.enable')
        self.send('Emulation.setDeviceMetricsOverride', width=width, height=height,
                  deviceScaleFactor=1, mobile=False)

    def _devtools_port(self, timeout=60.0):
        deadline = time.monotonic() + timeout
        lines = []
        while time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                if self.proc.poll() is not None:
                    break
                continue
            lines.append(line)
            if 'DevTools listening on ws://' in line:
                return int(line.split('ws://', 1)[1].split('/', 1)[0].rsplit(':', 1)[1])
        raise RuntimeError('chromium did not open its DevTools port:\n' + ''.join(lines[-20:]))

    def send(self, method, timeout=600.0, **params):
        """Call a CDP method; return its result (events in between are dropped)."""
        self._id += 1
        ident = self._id
        self.ws.send(json.dumps({'id': ident, 'method': method, 'params': params}))
        deadline = time.monotonic() + timeout
        while True:
            reply = json.loads(self.ws.recv(timeout=max(deadline - time.monotonic(), 0.1)))
            if reply.get('id') == ident:
                if 'error' in reply:
                    raise RuntimeError(f'{method}: {reply["error"]}')
                return reply.get('result', {})

    def open(self, url):
        self.send('Page.navigate', url=url)

    def evaluate(self, expression):
        """Value of a JavaScript expression in the page."""
        result = self.send('Runtime.evaluate', expression=expression, returnByValue=True)
        if 'exceptionDetails' in result:
            raise RuntimeError(f'{expression}: {result["exceptionDetails"]}')
        return result['result'].get('value')

    def screenshot(self, path=None):
        """The page as an ``(h, w, 3)`` uint8 array (and a PNG at ``path``)."""
        data = base64.b64decode(self.send('Page.captureScreenshot', format='png')['data'])
        if path is not None:
            with open(path, 'wb') as handle:
                handle.write(data)
        return np.asarray(Image.open(io.BytesIO(data)).convert('RGB'))

    def click(self, x, y):
        for kind in ('mouseMoved', 'mousePressed', 'mouseReleased'):
            self.send('Input.dispatchMouseEvent', type=kind, x=float(x), y=float(y),
                      button='left', clickCount=1 if kind != 'mouseMoved' else 0)

    def press_key(self, key):
        """Press and release a letter key (``'v'``)."""
        code = f'Key{key.upper()}'
        vk = ord(key.upper())
        self.send('Input.dispatchKeyEvent', type='keyDown', key=key, code=code, text=key,
                  windowsVirtualKeyCode=vk, nativeVirtualKeyCode=vk)
        self.send('Input.dispatchKeyEvent', type='keyUp', key=key, code=code,
                  windowsVirtualKeyCode=vk, nativeVirtualKeyCode=vk)

    def element_center(self, text, selector='button'):
        """Centre ``(x, y)`` of the first visible ``selector`` whose text contains ``text``."""
        rect = self.evaluate(
            f'(() => {{ for (const e of document.querySelectorAll({json.dumps(selector)})) {{'
            f' if (e.innerText && e.innerText.includes({json.dumps(text)})) {{'
            f' const r = e.getBoundingClientRect(); if (r.width > 0)'
            f' return [r.x + r.width / 2, r.y + r.height / 2]; }} }} return null; }})()')
        return rect

    def close_notification(self, text):
        """Click the close button of the notification that says ``text``; whether there was one."""
        center = self.evaluate(
            '(() => { let best = null; for (const d of document.querySelectorAll("div")) {'
            f' if (!d.innerText || !d.innerText.includes({json.dumps(text)})) continue;'
            ' const b = d.querySelector("button"); if (!b) continue;'
            ' const r = d.getBoundingClientRect();'
            ' if (!best || r.width * r.height < best[0]) {'
            ' const c = b.getBoundingClientRect();'
            ' best = [r.width * r.height, c.x + c.width / 2, c.y + c.height / 2]; } }'
            ' return best && best.slice(1); })()')
        if center is None:
            return False
        self.click(*center)
        return True

    def canvas_rect(self):
        """``[x, y, width, height]`` of the largest canvas (the 3-D view), or None."""
        return self.evaluate(
            '(() => { let best = null; for (const c of document.querySelectorAll("canvas")) {'
            ' const r = c.getBoundingClientRect();'
            ' if (!best || r.width * r.height > best[2] * best[3])'
            ' best = [r.x, r.y, r.width, r.height]; } return best; })()')

    def close(self):
        try:
            self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
            self._profile.cleanup()


def project(points_world, camera_position, look_at, fov, rect, up=(0.0, 0.0, 1.0)):
    """
    Pixels ``(n, 2)`` of world points seen by a look-at pinhole camera filling ``rect``.

    ``fov`` is the vertical field of view (rad), as the page's camera; ``rect`` the canvas
    ``[x, y, width, height]`` in page pixels.
    """
    eye = np.asarray(camera_position, float)
    forward = np.asarray(look_at, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, float))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    p = np.atleast_2d(np.asarray(points_world, float)) - eye
    x, y, z = p @ right, p @ down, p @ forward
    x0, y0, w, h = rect
    f = 0.5 * h / np.tan(0.5 * fov)
    return np.stack((x0 + 0.5 * w + f * x / z, y0 + 0.5 * h + f * y / z), axis=1)
