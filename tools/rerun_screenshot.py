"""A screenshot of a Rerun recording in the web viewer, as a user opening it sees it.

    python -m tools.rerun_screenshot [RUN.rrd] [--out docs/images/rerun_layout.png]

Hosts the web viewer with ``rerun --serve-web`` (the venv's rerun, bound to 127.0.0.1 on free
ports, analytics off, a throw-away HOME), serves the file over HTTP on another free port and opens
``viewer/?url=http://.../run.rrd`` in headless Chromium (WebGL through SwiftShader), driven over
the DevTools protocol on a pipe: the viewer downloads the whole file at once (over the viewer's
gRPC proxy it streams in chunk by chunk, minutes with a software renderer). After ``--wait``
seconds (the viewer needs tens of seconds to load) it saves the page as PNG.
The recording defaults to
``runs/demo/run.rrd`` (what ``make demo`` writes). Chromium: ``bash tools/install_chromium.sh``.
"""
from __future__ import annotations

import argparse
import base64
import fcntl
import functools
import http.server
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _wait_port(port, deadline):
    while True:
        try:
            socket.create_connection(('127.0.0.1', port), timeout=0.5).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise SystemExit(f'rerun_screenshot: nothing listens on port {port}')
            time.sleep(0.2)


class _CorsHandler(http.server.SimpleHTTPRequestHandler):
    """Static files, readable from the viewer's origin (another port)."""

    def end_headers(self):
        self.send_header('Access-Control-Allow-Origin', '*')
        super().end_headers()

    def log_message(self, *args):
        pass


class _DevTools:
    """Chromium's DevTools protocol over ``--remote-debugging-pipe`` (fds 3 and 4 of the
    browser: JSON messages ended by a NUL byte)."""

    def __init__(self, argv, stderr):
        to_r, to_w = os.pipe()                  # commands: us -> browser fd 3
        from_r, from_w = os.pipe()              # replies: browser fd 4 -> us
        # out of the way of fds 3 and 4 before they are set in the child
        to_r2, from_w2 = (fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_r, from_w))
        os.close(to_r)
        os.close(from_w)

        def child():
            os.dup2(to_r2, 3)
            os.dup2(from_w2, 4)
        self.proc = subprocess.Popen(argv, preexec_fn=child, close_fds=False,
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=stderr, start_new_session=True)
        os.close(to_r2)
        os.close(from_w2)
        self._w = os.fdopen(to_w, 'wb', buffering=0)
        self._r = os.fdopen(from_r, 'rb', buffering=0)
        self._buf = b''
        self._id = 0

    def call(self, method, params=None, session=None):
        self._id += 1
        msg = {'id': self._id, 'method': method, 'params': params or {}}
        if session:
            msg['sessionId'] = session
        self._w.write(json.dumps(msg).encode() + b'\0')
        while True:
            while b'\0' in self._buf:
                raw, self._buf = self._buf.split(b'\0', 1)
                reply = json.loads(raw)
                if reply.get('id') == self._id:
                    if 'error' in reply:
                        raise RuntimeError(f'{method}: {reply["error"]}')
                    return reply.get('result', {})
            data = self._r.read(1 << 16)
            if not data:
                raise RuntimeError('the browser closed its DevTools pipe')
            self._buf += data

    def close(self):
        try:
            self.call('Browser.close')
            self.proc.wait(timeout=30)
        except Exception:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)


def screenshot(rrd, out, wait_s=90.0, size=(1600, 1000), chromium=None):
    rerun = Path(sys.executable).parent / 'rerun'
    if not rerun.exists():
        raise SystemExit('rerun_screenshot: no rerun binary next to this Python (make install)')
    chromium = chromium or shutil.which('chromium')
    if chromium is None:
        raise SystemExit('rerun_screenshot: no chromium on PATH (bash tools/install_chromium.sh)')
    with tempfile.TemporaryDirectory(prefix='rerun_shot_') as tmp:
        home = Path(tmp)
        env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / 'cfg'),
                   XDG_DATA_HOME=str(home / 'data'), XDG_CACHE_HOME=str(home / 'cache'))
        subprocess.run([str(rerun), 'analytics', 'disable'], env=env, timeout=60,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        grpc, web = _free_port(), _free_port()
        log = open(home / 'rerun.log', 'w')
        server = subprocess.Popen(
            [str(rerun), '--serve-web', '--bind', '127.0.0.1', '--port', str(grpc),
             '--web-viewer-port', str(web)], env=env, stdout=log, stderr=log,
            start_new_session=True)
        rrd = Path(rrd).resolve()
        files = http.server.ThreadingHTTPServer(
            ('127.0.0.1', 0), functools.partial(_CorsHandler, directory=str(rrd.parent)))
        threading.Thread(target=files.serve_forever, daemon=True).start()
        browser = None
        try:
            deadline = time.monotonic() + 60
            _wait_port(grpc, deadline)
            _wait_port(web, deadline)
            inner = (f'http://127.0.0.1:{files.server_address[1]}/'
                     f'{urllib.parse.quote(rrd.name)}')
            url = f'http://127.0.0.1:{web}/?url={urllib.parse.quote(inner, safe="")}'
            browser = _DevTools(
                [chromium, '--headless', '--no-sandbox', '--use-angle=swiftshader',
                 '--enable-unsafe-swiftshader', '--disable-gpu-sandbox', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update',
                 '--disable-sync', '--hide-scrollbars', f'--user-data-dir={home / "chromium"}',
                 f'--window-size={size[0]},{size[1]}', '--remote-debugging-pipe',
                 'about:blank'], stderr=open(home / 'chromium.log', 'w'))
            target = browser.call('Target.createTarget', {'url': 'about:blank'})['targetId']
            session = browser.call('Target.attachToTarget',
                                   {'targetId': target, 'flatten': True})['sessionId']
            browser.call('Emulation.setDeviceMetricsOverride',
                         {'width': size[0], 'height': size[1], 'deviceScaleFactor': 1,
                          'mobile': False}, session)
            browser.call('Page.navigate', {'url': url}, session)
            time.sleep(wait_s)
            png = browser.call('Page.captureScreenshot', {'format': 'png'}, session)['data']
            out = Path(out)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(base64.b64decode(png))
        finally:
            if browser is not None:
                browser.close()
            files.shutdown()
            files.server_close()
            os.killpg(server.pid, signal.SIGTERM)
            server.wait(timeout=30)
            log.close()
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('rrd', nargs='?', default=str(ROOT / 'runs' / 'demo' / 'run.rrd'))
    ap.add_argument('--out', default=str(ROOT / 'docs' / 'images' / 'rerun_layout.png'))
    ap.add_argument('--wait', type=float, default=90.0,
                    help='seconds to let the viewer load before the screenshot (default 90)')
    ap.add_argument('--size', default='1600x1000', help='window size, WIDTHxHEIGHT')
    args = ap.parse_args(argv)
    if not Path(args.rrd).exists():
        raise SystemExit(f'rerun_screenshot: {args.rrd} does not exist (make demo writes '
                         f'runs/demo/run.rrd)')
    w, h = (int(v) for v in args.size.split('x'))
    print(screenshot(args.rrd, args.out, args.wait, (w, h)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
