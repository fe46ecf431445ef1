"""HTTP client for a GoPro (HERO9 and later) over its wired USB network (Open GoPro HTTP API).

Facts used (Open GoPro HTTP specification):

- the camera answers on ``172.2X.1YZ.51:8080`` where ``XYZ`` are the last three digits of its serial;
- ``/gopro/camera/control/wired_usb?p=1`` enables control over USB;
- ``/gopro/camera/keep_alive`` must be sent regularly (every 3 s is the recommended practice);
- ``/gopro/camera/state`` returns ``{"status": {id: value}, "settings": {id: value}}``;
  status 8 is "system busy", status 10 is "encoding";
- ``/gopro/camera/shutter/start`` and ``.../stop``;
- ``/gopro/camera/setting?setting=ID&option=OPTION``;
- ``/gopro/camera/set_date_time?date=YYYY_MM_DD&time=HH_MM_SS&tzone=MIN&dst=0|1``;
- ``/gopro/media/list`` and ``/videos/DCIM/<folder>/<file>`` for download (HTTP Range supported);
- ``/gopro/camera/stream/start?port=8554`` and ``.../stop``: the framing preview (UDP MPEG-TS),
  which cannot run while recording.
"""

from __future__ import annotations

import datetime as _dt
import http.client
import json
import re
import threading
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

PORT = 8080
"""HTTP port of the camera's API."""

PREVIEW_UDP_PORT = 8554
"""Default UDP port of the framing preview stream."""

STATUS_BUSY = 8
"""Status id: system busy (loading presets, changing settings...)."""

STATUS_ENCODING = 10
"""Status id: encoding (recording video)."""

SETTING_RESOLUTION = 2
SETTING_FPS = 3
SETTING_VIDEO_LENS = 121
SETTING_ANTI_FLICKER = 134
SETTING_HYPERSMOOTH = 135

RESOLUTION_OPTIONS = {"4K": 1, "2.7K": 4, "2.7K_4:3": 6, "1080": 9, "4K_4:3": 18, "5.3K": 100}
"""Video resolution (setting 2) options."""

FPS_OPTIONS = {240: 0, 120: 1, 100: 2, 60: 5, 50: 6, 30: 8, 25: 9, 24: 10, 200: 13}
"""Frames per second (setting 3) options (the camera records 240 as 240000/1001, etc.)."""

LENS_OPTIONS = {"wide": 0, "narrow": 2, "superview": 3, "linear": 4, "linear_horizon_leveling": 8}
"""Video lens (setting 121) options."""

ANTI_FLICKER_OPTIONS = {"60Hz": 2, "50Hz": 3}
"""Anti-flicker (setting 134) options (HERO9 to HERO12 values)."""

HYPERSMOOTH_OFF = 0
"""HyperSmooth (setting 135) option "off": stabilisation warps frames, so calibration needs it off."""


class GoProError(RuntimeError):
    """Base class of GoPro errors."""


class CameraUnreachable(GoProError):
    """No HTTP answer from the camera's address."""


class CameraBusy(GoProError):
    """The camera is busy or recording and refused, or would refuse, the command."""


class MediaNotFound(GoProError):
    """The requested media file is not on the camera."""


class DownloadError(GoProError):
    """A download broke off; the partial file is kept for resuming."""


def address_from_serial(serial: str) -> str:
    """IP address of a camera's wired USB interface from its serial number.

    The last three digits ``XYZ`` give ``172.2X.1YZ.51``.

    Raises
    ------
    ValueError
        When the serial does not end with three digits.
    """
    m = re.search(r"(\d)(\d)(\d)$", str(serial).strip())
    if not m:
        raise ValueError(f"GoPro serial {serial!r} does not end with three digits")
    x, y, z = m.groups()
    return f"172.2{x}.1{y}{z}.51"


@dataclass(frozen=True)
class MediaFile:
    """One file on the camera's card.

    Attributes
    ----------
    folder : str
        DCIM sub-folder, e.g. ``"100GOPRO"``.
    name : str
        File name, e.g. ``"GX010042.MP4"``.
    size_bytes : int
        File size (-1 when the camera did not say).
    created_s : int
        Creation time, seconds since the epoch in the camera's local time (0 when unknown).
    """

    folder: str
    name: str
    size_bytes: int = -1
    created_s: int = 0

    @property
    def path(self) -> str:
        """``folder/name`` as used in media URLs."""
        return f"{self.folder}/{self.name}"

    @property
    def recording(self) -> tuple[str, str] | None:
        """``(prefix, number)`` that the chapters of one recording share, ``None`` for non-chaptered names."""
        m = re.match(r"^(G[HX])\d{2}(\d{4})\.MP4$", self.name, re.IGNORECASE)
        return (m.group(1).upper(), m.group(2)) if m else None


class GoPro:
    """A GoPro over the wired USB network (or any host/port, e.g. :class:`FakeGoPro`).

    Parameters
    ----------
    serial : str, optional
        Camera serial; gives the address with :func:`address_from_serial`.
    host : str, optional
        Address to use instead (e.g. ``"127.0.0.1"`` for the fake camera).
    port : int
        HTTP port (8080 on a camera).
    timeout_s : float
        Socket timeout for each request, in seconds.
    keep_alive_s : float
        Period of the keep-alive thread started by :meth:`open` (at most 3 s).

    Use as a context manager: ``with GoPro(serial="C3461324567890") as cam: cam.start_recording()``.
    """

    def __init__(self, serial: str | None = None, *, host: str | None = None, port: int = PORT,
                 timeout_s: float = 5.0, keep_alive_s: float = 2.5):
        if host is None:
            if serial is None:
                raise ValueError("give the camera's serial or a host address")
            host = address_from_serial(serial)
        if not 0 < keep_alive_s <= 3.0:
            raise ValueError(f"keep_alive_s must be in (0, 3] seconds, got {keep_alive_s}")
        self.host, self.port, self.timeout_s, self.keep_alive_s = host, int(port), float(timeout_s), float(keep_alive_s)
        self.keep_alive_failures = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- plumbing
    def _conn(self, timeout_s: float | None = None) -> http.client.HTTPConnection:
        return http.client.HTTPConnection(self.host, self.port, timeout=timeout_s or self.timeout_s)

    def _unreachable(self, exc: Exception) -> CameraUnreachable:
        return CameraUnreachable(f"GoPro at {self.host}:{self.port} unreachable ({exc.__class__.__name__}: {exc}); "
                                 "check the USB cable and that the camera is on")

    def _get(self, path: str, **params) -> bytes:
        """GET ``path`` with query ``params``; returns the body of a 200 answer."""
        url = path + ("?" + urllib.parse.urlencode(params) if params else "")
        conn = self._conn()
        try:
            conn.request("GET", url)
            resp = conn.getresponse()
            body = resp.read()
        except (OSError, http.client.HTTPException) as exc:
            raise self._unreachable(exc) from None
        finally:
            conn.close()
        if resp.status == 200:
            return body
        text = body[:200].decode("utf-8", "replace").strip()
        if resp.status in (409, 503):
            raise CameraBusy(f"GoPro busy: {url} refused with HTTP {resp.status} {text}")
        if resp.status == 404:
            raise MediaNotFound(f"GoPro: {url} not found (HTTP 404)")
        raise GoProError(f"GoPro: {url} failed with HTTP {resp.status} {text}")

    def _json(self, path: str, **params) -> dict:
        body = self._get(path, **params)
        try:
            return json.loads(body or b"{}")
        except json.JSONDecodeError as exc:
            raise GoProError(f"GoPro: {path} answered invalid JSON ({exc})") from None

    # ---------------------------------------------------------------- session
    def open(self) -> GoPro:
        """Enable wired control and start the keep-alive thread."""
        self.enable_wired_control(True)
        self.keep_alive()
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._keep_alive_loop, name="gopro-keep-alive", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the keep-alive thread (the camera keeps its state)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.timeout_s + 1)
            self._thread = None

    def __enter__(self) -> GoPro:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _keep_alive_loop(self) -> None:
        while not self._stop.wait(self.keep_alive_s):
            try:
                self.keep_alive()
            except GoProError:
                self.keep_alive_failures += 1

    def enable_wired_control(self, enable: bool = True) -> None:
        """Claim (or release) control of the camera over USB."""
        self._get("/gopro/camera/control/wired_usb", p=int(bool(enable)))

    def keep_alive(self) -> None:
        """Reset the camera's keep-alive timer (sent by the thread every ``keep_alive_s``)."""
        self._get("/gopro/camera/keep_alive")

    # ---------------------------------------------------------------- state
    def state(self) -> dict:
        """Camera state: ``{"status": {int id: value}, "settings": {int id: value}}``."""
        raw = self._json("/gopro/camera/state")
        return {k: {int(i): v for i, v in raw.get(k, {}).items()} for k in ("status", "settings")}

    def is_recording(self) -> bool:
        """True while the camera is encoding."""
        return bool(self.state()["status"].get(STATUS_ENCODING, 0))

    def wait_ready(self, timeout_s: float = 5.0, *, allow_encoding: bool = False, poll_s: float = 0.05) -> None:
        """Wait until the camera is neither busy nor (unless allowed) encoding.

        Raises
        ------
        CameraBusy
            When the camera stays busy for ``timeout_s`` seconds.
        """
        t_end = time.monotonic() + timeout_s
        while True:
            status = self.state()["status"]
            busy = bool(status.get(STATUS_BUSY, 0))
            encoding = bool(status.get(STATUS_ENCODING, 0)) and not allow_encoding
            if not busy and not encoding:
                return
            if time.monotonic() >= t_end:
                what = "busy" if busy else "recording"
                raise CameraBusy(f"GoPro at {self.host}:{self.port} still {what} after {timeout_s:g} s")
            time.sleep(poll_s)

    # ---------------------------------------------------------------- control
    def start_recording(self, timeout_s: float = 5.0) -> None:
        """Start recording (shutter on) once the camera is ready."""
        self.wait_ready(timeout_s)
        self._get("/gopro/camera/shutter/start")

    def stop_recording(self, timeout_s: float = 5.0) -> None:
        """Stop recording (shutter off)."""
        self.wait_ready(timeout_s, allow_encoding=True)
        self._get("/gopro/camera/shutter/stop")

    def set_setting(self, setting_id: int, option: int, timeout_s: float = 5.0) -> None:
        """Set one setting by id and option id (refused while recording).

        Raises
        ------
        CameraBusy
            When the camera is recording or stays busy.
        """
        self.wait_ready(timeout_s)
        self._get("/gopro/camera/setting", setting=int(setting_id), option=int(option))

    def configure(self, *, resolution: str = "1080", fps: int = 240, lens: str = "linear",
                  hypersmooth: bool = False, anti_flicker: str = "50Hz") -> None:
        """Set the video settings used for ball capture.

        Parameters
        ----------
        resolution : str
            A key of :data:`RESOLUTION_OPTIONS` (``"1080"`` allows 240 fps on HERO10).
        fps : int
            A key of :data:`FPS_OPTIONS` (up to 240).
        lens : str
            A key of :data:`LENS_OPTIONS`; ``"linear"`` removes most of the fisheye distortion.
        hypersmooth : bool
            Stabilisation; keep it off (it warps frames, breaking calibration).
        anti_flicker : str
            ``"50Hz"`` or ``"60Hz"``: the mains frequency of the hall lighting.
        """
        for name, table, key in (("resolution", RESOLUTION_OPTIONS, resolution), ("fps", FPS_OPTIONS, fps),
                                 ("lens", LENS_OPTIONS, lens), ("anti_flicker", ANTI_FLICKER_OPTIONS, anti_flicker)):
            if key not in table:
                raise ValueError(f"GoPro {name}={key!r} not supported; choose one of {sorted(table, key=str)}")
        self.set_setting(SETTING_RESOLUTION, RESOLUTION_OPTIONS[resolution])
        self.set_setting(SETTING_FPS, FPS_OPTIONS[fps])
        self.set_setting(SETTING_VIDEO_LENS, LENS_OPTIONS[lens])
        self.set_setting(SETTING_HYPERSMOOTH, 1 if hypersmooth else HYPERSMOOTH_OFF)
        self.set_setting(SETTING_ANTI_FLICKER, ANTI_FLICKER_OPTIONS[anti_flicker])

    def set_date_time(self, when: _dt.datetime | None = None) -> None:
        """Set the camera clock (default: now; a naive ``when`` is taken as local time)."""
        when = when or _dt.datetime.now()
        if when.tzinfo is None:
            when = when.astimezone()
        offset = when.utcoffset() or _dt.timedelta(0)
        dst = bool(when.dst())
        tzone_min = int((offset - (when.dst() or _dt.timedelta(0))).total_seconds() // 60)
        self._get("/gopro/camera/set_date_time", date=f"{when.year}_{when.month}_{when.day}",
                  time=f"{when.hour}_{when.minute}_{when.second}", tzone=tzone_min, dst=int(dst))

    def start_preview(self, port: int = PREVIEW_UDP_PORT) -> None:
        """Start the framing preview (UDP MPEG-TS to this host's ``port``); not while recording."""
        self.wait_ready()
        self._get("/gopro/camera/stream/start", port=int(port))

    def stop_preview(self) -> None:
        """Stop the framing preview."""
        self._get("/gopro/camera/stream/stop")

    # ---------------------------------------------------------------- media
    def media_list(self) -> list[MediaFile]:
        """Files on the card, in the camera's order."""
        raw = self._json("/gopro/media/list")
        out = []
        for d in raw.get("media", []):
            for f in d.get("fs", []):
                out.append(MediaFile(folder=str(d["d"]), name=str(f["n"]), size_bytes=int(f.get("s", -1)),
                                     created_s=int(f.get("cre", 0))))
        return out

    def _find(self, name: str) -> MediaFile:
        for m in self.media_list():
            if m.name == name or m.path == name:
                return m
        raise MediaNotFound(f"GoPro at {self.host}:{self.port}: no media file {name!r} on the card")

    def chapters(self, media: MediaFile | str) -> list[MediaFile]:
        """All chapters of the recording that ``media`` belongs to, in chapter order."""
        media = self._find(media) if isinstance(media, str) else media
        rec = media.recording
        if rec is None:
            return [media]
        same = [m for m in self.media_list() if m.folder == media.folder and m.recording == rec]
        return sorted(same, key=lambda m: m.name[2:4])

    def download(self, media: MediaFile | str, dest_dir, *, progress: bool = True, retries: int = 3,
                 chunk_bytes: int = 1 << 20) -> Path:
        """Download one file to ``dest_dir`` (streamed; resumed with HTTP Range after a cut).

        The data go to ``NAME.part``; it is renamed to ``NAME`` once complete. A ``.part`` left by
        an earlier broken download is resumed; a complete ``NAME`` of the right size is kept as is.

        Parameters
        ----------
        media : MediaFile or str
            The file, or its name / ``folder/name``.
        dest_dir : str or Path
            Destination folder (created).
        progress : bool
            Show a tqdm progress bar.
        retries : int
            Resumes attempted after a broken connection before giving up.
        chunk_bytes : int
            Read size.

        Raises
        ------
        MediaNotFound
            When the file is not on the card.
        DownloadError
            When the transfer keeps failing; the ``.part`` file is kept.
        """
        media = self._find(media) if isinstance(media, str) else media
        dest_dir = Path(dest_dir)
        dest_dir.mkdir(parents=True, exist_ok=True)
        final = dest_dir / media.name
        part = dest_dir / (media.name + ".part")
        if final.is_file() and media.size_bytes >= 0 and final.stat().st_size == media.size_bytes:
            return final  # already downloaded
        url = f"/videos/DCIM/{urllib.parse.quote(media.folder)}/{urllib.parse.quote(media.name)}"
        bar = tqdm(total=media.size_bytes if media.size_bytes >= 0 else None, unit="B", unit_scale=True,
                   desc=media.name, disable=not progress, initial=part.stat().st_size if part.exists() else 0)
        try:
            for attempt in range(retries + 1):
                have = part.stat().st_size if part.exists() else 0
                try:
                    total = self._fetch(url, part, have, chunk_bytes, bar, media)
                except DownloadError:
                    if attempt == retries:
                        raise
                    continue
                if total is not None and part.stat().st_size == total:
                    part.replace(final)
                    return final
        finally:
            bar.close()
        raise DownloadError(f"GoPro download of {media.path} incomplete after {retries} retries; partial data kept in {part}")

    def _fetch(self, url: str, part: Path, have: int, chunk_bytes: int, bar, media: MediaFile) -> int | None:
        """One GET (ranged from ``have``), appending to ``part``; returns the total file size."""
        conn = self._conn()
        try:
            headers = {"Range": f"bytes={have}-"} if have else {}
            try:
                conn.request("GET", url, headers=headers)
                resp = conn.getresponse()
            except (OSError, http.client.HTTPException) as exc:
                raise DownloadError(f"GoPro download of {media.path} failed at byte {have}: {exc}; "
                                    f"partial data kept in {part}") from None
            if resp.status == 404:
                raise MediaNotFound(f"GoPro at {self.host}:{self.port}: media {media.path} not found (HTTP 404)")
            if resp.status == 416 and have:
                return have  # already complete
            if resp.status == 206:
                m = re.match(r"bytes (\d+)-\d+/(\d+)", resp.getheader("Content-Range", ""))
                if not m or int(m.group(1)) != have:
                    raise DownloadError(f"GoPro download of {media.path}: bad Content-Range "
                                        f"{resp.getheader('Content-Range')!r} for resume at byte {have}")
                total, mode = int(m.group(2)), "ab"
            elif resp.status == 200:
                length = resp.getheader("Content-Length")
                total, mode = (int(length) if length else None), "wb"
                if have:
                    bar.reset(total=total)
            else:
                raise DownloadError(f"GoPro download of {media.path} refused with HTTP {resp.status}")
            got = have if mode == "ab" else 0
            with open(part, mode) as f:
                try:
                    while True:
                        buf = resp.read(chunk_bytes)
                        if not buf:
                            break
                        f.write(buf)
                        got += len(buf)
                        bar.update(len(buf))
                except (OSError, http.client.HTTPException) as exc:
                    raise DownloadError(f"GoPro download of {media.path} broke off at byte {got}: "
                                        f"{exc.__class__.__name__}; partial data kept in {part}") from None
            if total is not None and got < total:
                raise DownloadError(f"GoPro download of {media.path} broke off at byte {got} of {total}; "
                                    f"partial data kept in {part}")
            return total
        finally:
            conn.close()

    def download_recording(self, media: MediaFile | str, dest_dir, **kw) -> list[Path]:
        """Download every chapter of a recording; returns the local paths in chapter order."""
        return [self.download(m, dest_dir, **kw) for m in self.chapters(media)]

