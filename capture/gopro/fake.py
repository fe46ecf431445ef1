"""A fake GoPro: a loopback HTTP server implementing the Open GoPro endpoints that
:class:`capture.gopro.GoPro` uses, serving simulated MP4 files as the card's media.

The real client runs against it unchanged; only ``host``/``port`` differ::

    with FakeGoPro("clip.mp4") as fake:
        with GoPro(host=fake.host, port=fake.port) as cam:
            cam.start_recording(); cam.stop_recording()
            cam.download_recording(cam.media_list()[-1], "out/")
"""

from __future__ import annotations

import json
import re
import shutil
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from capture.gopro.models import (
    PRESET_GROUP_PHOTO, STATUS_BATTERY_PCT, STATUS_BUSY, STATUS_ENCODING,
    STATUS_OVERHEATING, STATUS_PRESET_GROUP, STATUS_REMAINING_VIDEO_S, STATUS_SD_REMAINING_KB, STATUS_SD_STATUS,
    CameraModel, model_by_name,
)


class FakeGoPro:
    """Loopback fake camera (context manager; ``127.0.0.1`` on an ephemeral port).

    Parameters
    ----------
    mp4_path : str, Path or list of them
        The simulated recording; a list gives its chapters (served as ``GX01nnnn.MP4``,
        ``GX02nnnn.MP4``...). Every shutter start/stop adds one such recording to the card.
    n_recordings : int
        Recordings already on the card at start.
    busy_s : float
        After each shutter or setting command, the camera reports "busy" (status 8) and refuses
        commands with HTTP 503 for this many seconds.
    model : str or CameraModel
        The camera's model profile (``"HERO10"`` to ``"HERO13"``, or ``"HERO9"``, which refuses
        wired control): model number in ``/gopro/camera/info``, the options it accepts (others
        answer 403 with the supported options), ``tzone``/``dst`` refused on HERO9/10.
    preset_group : int
        Preset group at power-on (default: photo; there the shutter takes a photo).
    finish_s : float
        After the shutter stop, the camera keeps encoding this long (finishing the file) and the
        new file is listed only then.
    battery_pct, sd_status, sd_free_kb, overheating : int, int, int, bool
        Health statuses (70, 33, 54, 6); ``sd_status=2`` is "no card", ``sd_free_kb=0`` a full
        card: the shutter then does not start encoding.
    ignore_settings : set of int
        Fault injection: these settings answer 200 but keep their old option (a read-back
        shows it).
    cut_after_bytes : int, optional
        Fault injection: the next media download closes the connection after this many bytes
        (once), to test resume.
    folder : str
        DCIM folder name.

    Attributes
    ----------
    host, port : str, int
        Where the fake listens.
    settings : dict[int, int]
        Current settings (id -> option).
    requests : list[str]
        Request paths received, in order.
    keep_alive_times : list[float]
        ``time.monotonic()`` of each keep-alive received.
    wired_control : bool
        Whether wired USB control was enabled.
    date_time : dict or None
        Last ``set_date_time`` query.
    preview_port : int or None
        UDP port of the running preview, ``None`` when stopped.
    """

    def __init__(self, mp4_path, *, n_recordings: int = 1, busy_s: float = 0.0,
                 cut_after_bytes: int | None = None, folder: str = "100GOPRO", model="HERO12",
                 preset_group: int = PRESET_GROUP_PHOTO, finish_s: float = 0.05, battery_pct: int = 80,
                 sd_status: int = 0, sd_free_kb: int = 50_000_000, overheating: bool = False,
                 ignore_settings=()):
        chapters = [Path(p) for p in (mp4_path if isinstance(mp4_path, (list, tuple)) else [mp4_path])]
        for p in chapters:
            if not p.is_file():
                raise FileNotFoundError(f"FakeGoPro: simulated video not found: {p}")
        self.chapters = chapters
        self.folder = folder
        self.busy_s = float(busy_s)
        self.cut_after_bytes = cut_after_bytes
        self.model: CameraModel = model if isinstance(model, CameraModel) else model_by_name(model)
        self.settings: dict[int, int] = {2: 9, 3: 5, 121: 0, 134: self.model.anti_flicker["60Hz"], 135: 1, 59: 4}
        if self.model.control_mode:
            self.settings[175] = 0
        self.preset_group = int(preset_group)
        self.ignore_settings = set(ignore_settings)
        self.finish_s = float(finish_s)
        self.health = {STATUS_BATTERY_PCT: int(battery_pct), STATUS_SD_STATUS: int(sd_status),
                       STATUS_SD_REMAINING_KB: int(sd_free_kb), STATUS_OVERHEATING: int(bool(overheating))}
        self._finish_at = 0.0
        self._pending: list[str] = []
        self.requests: list[str] = []
        self.keep_alive_times: list[float] = []
        self.wired_control = False
        self.date_time: dict | None = None
        self.preview_port: int | None = None
        self.encoding = False
        self._busy_until = 0.0
        self._media: dict[str, Path] = {}
        self._next_number = 1
        self._lock = threading.Lock()
        for _ in range(n_recordings):
            self._add_recording()
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self.host, self.port = "127.0.0.1", 0

    # ------------------------------------------------------------ state
    def _add_recording(self) -> None:
        n = self._next_number
        self._next_number += 1
        for c, p in enumerate(self.chapters, start=1):
            self._media[f"GX{c:02d}{n:04d}.MP4"] = p

    def _settle(self) -> None:
        """List a stopped recording once its file is finished."""
        if self._pending and time.monotonic() >= self._finish_at:
            self._pending = []
            self._add_recording()

    @property
    def can_record(self) -> bool:
        """Whether the shutter would start encoding (a card present with space, not overheating)."""
        h = self.health
        return h[STATUS_SD_STATUS] == 0 and h[STATUS_SD_REMAINING_KB] > 0 and not h[STATUS_OVERHEATING]

    @property
    def busy(self) -> bool:
        """True while the simulated busy period lasts."""
        return time.monotonic() < self._busy_until

    def _set_busy(self) -> None:
        self._busy_until = time.monotonic() + self.busy_s

    def media_names(self) -> list[str]:
        """Names of the files on the simulated card."""
        return list(self._media)

    # ------------------------------------------------------------ server
    def start(self) -> FakeGoPro:
        """Start serving on ``127.0.0.1`` (ephemeral port)."""
        fake = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # keep test output clean
                pass

            def do_GET(self):
                fake._handle(self)

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self.host, self.port = self._server.server_address[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="fake-gopro", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> FakeGoPro:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------ endpoints
    def _handle(self, h: BaseHTTPRequestHandler) -> None:
        url = urllib.parse.urlsplit(h.path)
        q = {k: v[-1] for k, v in urllib.parse.parse_qs(url.query).items()}
        path = url.path
        with self._lock:
            self.requests.append(h.path)
        if path.startswith("/videos/DCIM/"):
            return self._serve_media(h, path)
        if path == "/gopro/camera/keep_alive":
            self.keep_alive_times.append(time.monotonic())
            return self._reply(h, 200, {})
        if path == "/gopro/camera/state":
            self._settle()
            finishing = time.monotonic() < self._finish_at
            status = {str(STATUS_BUSY): int(self.busy), str(STATUS_ENCODING): int(self.encoding or finishing),
                      str(STATUS_PRESET_GROUP): self.preset_group,
                      str(STATUS_REMAINING_VIDEO_S): self.health[STATUS_SD_REMAINING_KB] // 45_000,
                      **{str(k): v for k, v in self.health.items()}}
            return self._reply(h, 200, {"status": status, "settings": {str(k): v for k, v in self.settings.items()}})
        if path == "/gopro/camera/info":
            return self._reply(h, 200, {"model_number": self.model.number, "model_name": self.model.name,
                                        "firmware_version": "fake", "serial_number": "C0000000000000",
                                        "ap_mac_addr": "000000000000", "ap_ssid": "fake"})
        if path == "/gopro/media/list":
            self._settle()
            fs = [{"n": n, "cre": str(int(p.stat().st_mtime)), "mod": str(int(p.stat().st_mtime)),
                   "s": str(p.stat().st_size)} for n, p in self._media.items()]
            return self._reply(h, 200, {"id": "fake", "media": [{"d": self.folder, "fs": fs}]})
        if path == "/gopro/camera/control/wired_usb":
            if not self.model.wired_control:
                return self._reply(h, 403, {"error": "wired control not supported"})
            self.wired_control = q.get("p") == "1"
            return self._reply(h, 200, {})
        if path == "/gopro/camera/shutter/stop":
            if self.encoding:
                self.encoding = False
                self._finish_at = time.monotonic() + self.finish_s
                self._pending = ["recording"]
            self._set_busy()
            return self._reply(h, 200, {})
        if self.busy:  # everything but the shutter stop waits (the SDK sends the stop at once)
            return self._reply(h, 503, {"error": "camera busy"})
        if path == "/gopro/camera/shutter/start":
            if self.preset_group == PRESET_GROUP_PHOTO:  # the shutter takes a photo
                self._media[f"GOPR{self._next_number:04d}.JPG"] = self.chapters[0]
                self._next_number += 1
            elif self.can_record:
                self.encoding = True
            self._set_busy()
            return self._reply(h, 200, {})
        if path == "/gopro/camera/presets/set_group":
            if self.encoding:
                return self._reply(h, 403, {"error": "not while encoding"})
            self.preset_group = int(q.get("id", self.preset_group))
            self._set_busy()
            return self._reply(h, 200, {})
        if path == "/gopro/camera/setting":
            if self.encoding:
                return self._reply(h, 403, {"error": "setting not available while encoding"})
            try:
                setting, option = int(q["setting"]), int(q["option"])
            except (KeyError, ValueError):
                return self._reply(h, 400, {"error": "bad setting query"})
            supported = self.model.options.get(setting, ())
            if option not in supported:
                return self._reply(h, 403, {"error": 1, "setting_id": setting, "option_id": option,
                                            "supported_options": [{"display_name": f"option {o}", "id": o}
                                                                  for o in supported]})
            if setting not in self.ignore_settings:
                self.settings[setting] = option
            self._set_busy()
            return self._reply(h, 200, {})
        if path == "/gopro/camera/set_date_time":
            if not re.fullmatch(r"\d{4}_\d{1,2}_\d{1,2}", q.get("date", "")) or \
                    not re.fullmatch(r"\d{1,2}_\d{1,2}_\d{1,2}", q.get("time", "")) or \
                    (not self.model.date_time_zone and ("tzone" in q or "dst" in q)):
                return self._reply(h, 400, {"error": "bad date/time"})
            self.date_time = q
            return self._reply(h, 200, {})
        if path == "/gopro/camera/stream/start":
            if self.encoding:
                return self._reply(h, 409, {"error": "cannot preview while encoding"})
            self.preview_port = int(q.get("port", 8554))
            return self._reply(h, 200, {})
        if path == "/gopro/camera/stream/stop":
            self.preview_port = None
            return self._reply(h, 200, {})
        return self._reply(h, 404, {"error": f"unknown endpoint {path}"})

    @staticmethod
    def _reply(h, code: int, body: dict) -> None:
        data = json.dumps(body).encode()
        h.send_response(code)
        h.send_header("Content-Type", "application/json")
        h.send_header("Content-Length", str(len(data)))
        h.end_headers()
        h.wfile.write(data)

    def _serve_media(self, h, path: str) -> None:
        parts = urllib.parse.unquote(path).split("/")
        if len(parts) != 5 or parts[3] != self.folder or parts[4] not in self._media:
            return self._reply(h, 404, {"error": "no such file"})
        src = self._media[parts[4]]
        size = src.stat().st_size
        start = 0
        m = re.fullmatch(r"bytes=(\d+)-", h.headers.get("Range", ""))
        if m:
            start = int(m.group(1))
            if start >= size:
                h.send_response(416)
                h.send_header("Content-Range", f"bytes */{size}")
                h.send_header("Content-Length", "0")
                h.end_headers()
                return
            h.send_response(206)
            h.send_header("Content-Range", f"bytes {start}-{size - 1}/{size}")
        else:
            h.send_response(200)
        h.send_header("Content-Type", "video/mp4")
        h.send_header("Content-Length", str(size - start))
        h.end_headers()
        cut, self.cut_after_bytes = self.cut_after_bytes, None
        with open(src, "rb") as f:
            f.seek(start)
            if cut is None:
                shutil.copyfileobj(f, h.wfile)
            else:
                h.wfile.write(f.read(cut))
                h.wfile.flush()
                h.close_connection = True
