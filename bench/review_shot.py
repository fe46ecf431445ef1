"""The demo's Rerun review in Rerun's web viewer, in a real headless browser: screenshots to look at.

Usage::

    PYTHONPATH=. python bench/review_shot.py [--out DIR] [--size 1366x768] [--wait 25] [--shots 3]

Records the demo session (``capture.run --demo``) into ``DIR/demo_session`` unless it is there,
serves its ``review.rrd`` with ``rerun --serve-web`` and opens the viewer in headless Chromium
(Debian: ``apt-get install chromium``; software WebGL) at the given window size, driven over
the DevTools protocol (``websocket-client``, in the ``bench`` extra). Saves ``--shots``
screenshots ``DIR/review_N.png``, ``--every`` seconds apart after ``--wait`` seconds (the viewer
opens playing the first flight at a tenth of real speed). Prints the time the writer took against
the time to read the session's events (the peer, same run), and where the screenshots are: look
at them.
"""

from __future__ import annotations

import argparse
import base64
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from capture.pipeline.ball_view import ball_view
from capture.review import write_rrd
from capture.session import open_session
from report_shot import demo_session  # bench/, on the path when run as a script


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_http(url: str, timeout_s: float) -> bytes:
    end = time.monotonic() + timeout_s
    while True:
        try:
            return urllib.request.urlopen(url, timeout=2).read()
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


class _DevTools:
    """The few DevTools-protocol calls a screenshot needs, over one page's websocket."""

    def __init__(self, ws_url: str):
        import websocket  # websocket-client: the bench extra

        self.ws = websocket.create_connection(ws_url, suppress_origin=True, timeout=60)
        self.n = 0

    def call(self, method: str, **params) -> dict:
        self.n += 1
        self.ws.send(json.dumps({"id": self.n, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self.n:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="review_shot", help="working directory")
    ap.add_argument("--size", default="1366x768", help="browser window, WIDTHxHEIGHT px")
    ap.add_argument("--wait", type=float, default=25.0, help="seconds before the first screenshot")
    ap.add_argument("--shots", type=int, default=3)
    ap.add_argument("--every", type=float, default=1.5, help="seconds between screenshots")
    ap.add_argument("--browser", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    session = demo_session(out)
    s = open_session(session)
    t0 = time.perf_counter()
    n = sum(len(b) for b in s.iter_events(1 << 20))
    t_read = time.perf_counter() - t0
    rrd = out / "review.rrd"
    t0 = time.perf_counter()
    stats = write_rrd(s, rrd, progress=False, ball_view=ball_view)
    t_write = time.perf_counter() - t0
    print(f"review {rrd}: {rrd.stat().st_size / 1e6:.1f} MB, {stats.n_events_logged} of {n} events logged, "
          f"written in {t_write:.2f} s ({t_write / t_read:.0f}x the {t_read:.2f} s of reading the events)")
    if not args.browser:
        print("no Chromium found (apt-get install chromium): no screenshot")
        return 1
    width, height = (int(v) for v in args.size.lower().split("x"))
    web, grpc, devtools = _free_port(), _free_port(), _free_port()
    rerun = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    server = subprocess.Popen([rerun, "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc), str(rrd)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with tempfile.TemporaryDirectory() as profile:
        browser = subprocess.Popen([args.browser, "--headless", "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader",
                                    "--enable-unsafe-swiftshader", "--hide-scrollbars", f"--window-size={width},{height}",
                                    f"--remote-debugging-port={devtools}", f"--user-data-dir={profile}", "about:blank"],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            _wait_http(f"http://127.0.0.1:{web}", 30)
            tabs = json.loads(_wait_http(f"http://127.0.0.1:{devtools}/json", 30))
            page = _DevTools(next(t for t in tabs if t["type"] == "page")["webSocketDebuggerUrl"])
            page.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)
            url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
            page.call("Page.navigate", url=url)
            time.sleep(args.wait)
            for i in range(args.shots):
                png = out / f"review_{i}.png"
                png.write_bytes(base64.b64decode(page.call("Page.captureScreenshot", format="png")["data"]))
                print(f"screenshot {png} ({width}x{height}): look at it")
                time.sleep(args.every)
        finally:
            browser.terminate()
            server.terminate()
            browser.wait(10)
            server.wait(10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
