"""HTTP client for a GoPro (HERO10 to HERO13 Black) over its wired USB network (Open GoPro HTTP API).

HERO9 Black cannot be controlled over USB (the specification says so); :meth:`GoPro.open` says
so in one line. Per-model answers (option ids, what each model accepts) are in
:mod:`capture.gopro.models`. Facts used (Open GoPro HTTP specification and its Python SDK):

- the camera answers on ``172.2X.1YZ.51:8080`` where ``XYZ`` are the last three digits of its serial;
- ``/gopro/camera/control/wired_usb?p=1`` enables control over USB;
- ``/gopro/camera/keep_alive`` must be sent regularly (every 3 s is the recommended practice);
- ``/gopro/camera/state`` returns ``{"status": {id: value}, "settings": {id: value}}``;
  status 8 is "system busy", status 10 is "encoding";
- ``/gopro/camera/shutter/start`` and ``.../stop``;
- ``/gopro/camera/setting?setting=ID&option=OPTION``; a refused option answers 403 with the
  options the camera supports;
- ``/gopro/camera/info`` (model number, firmware), ``/gopro/camera/presets/set_group?id=1000``
  (the video preset group; the SDK loads it before video settings);
- the shutter start is confirmed by status 10 (encoding) becoming 1; after the shutter stop the
  file is complete once encoding and busy (status 8) are both 0;
- ``/gopro/camera/set_date_time?date=YYYY_MM_DD&time=HH_MM_SS&tzone=MIN&dst=0|1`` (``tzone``/``dst``
  from HERO11 on);
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

from capture.gopro.models import (
    AUTO_POWER_DOWN_NEVER, CONTROL_MODE_PRO, FPS_OPTIONS, HYPERSMOOTH_OFF, LENS_OPTIONS, MODELS,
    PRESET_GROUP_VIDEO, RESOLUTION_OPTIONS, SD_STATUS, SETTING_ANTI_FLICKER, SETTING_AUTO_POWER_DOWN,
    SETTING_CONTROL_MODE, SETTING_FPS, SETTING_HYPERSMOOTH, SETTING_RESOLUTION, SETTING_VIDEO_LENS,
    STATUS_BATTERY_PCT, STATUS_BUSY, STATUS_COLD, STATUS_ENCODING, STATUS_OVERHEATING, STATUS_PRESET_GROUP,
    STATUS_REMAINING_VIDEO_S, STATUS_SD_REMAINING_KB, STATUS_SD_STATUS, UNKNOWN_MODEL, CameraModel,
    nearest_option,
)

PORT = 8080
"""HTTP port of the camera's API."""

PREVIEW_UDP_PORT = 8554
"""Default UDP port of the framing preview stream."""

class GoProError(RuntimeError):
    """Base class of GoPro errors."""


class CameraUnreachable(GoProError):
    """No HTTP answer from the camera's address."""


class SettingRefused(GoProError):
    """The camera refused a setting (HTTP 403) and offered no close option."""


class CameraNotReady(GoProError):
    """The camera cannot record now (no SD card, card full, overheating, did not start...)."""


class CameraBusy(GoProError):
    """The camera is busy or recording and refused, or would refuse, the command."""


class MediaNotFound(GoProError):
    """The requested media file is not on the camera."""


class DownloadError(GoProError):
    """A download broke off; the partial file is kept for resuming."""


class _Refused(GoProError):
    """HTTP 403 from the camera; ``supported`` lists ``(option id, display name)`` it offered."""

    def __init__(self, url: str, body: bytes):
        try:
            doc = json.loads(body or b"{}")
        except json.JSONDecodeError:
            doc = {}
        offered = doc.get("supported_options") or [] if isinstance(doc, dict) else []
        self.supported = [(int(o["id"]), str(o.get("display_name", o["id"]))) for o in offered
                          if isinstance(o, dict) and "id" in o]
        super().__init__(f"GoPro refused {url} (HTTP 403)")


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
        self.model: CameraModel | None = None
        self.notes: list[str] = []
        """Substitutions made for refused settings, one line each."""
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
        if resp.status == 403:
            raise _Refused(url, body)
        raise GoProError(f"GoPro: {url} failed with HTTP {resp.status} {text}")

    def _json(self, path: str, **params) -> dict:
        body = self._get(path, **params)
        try:
            return json.loads(body or b"{}")
        except json.JSONDecodeError as exc:
            raise GoProError(f"GoPro: {path} answered invalid JSON ({exc})") from None

    # ---------------------------------------------------------------- session
    def open(self) -> GoPro:
        """Claim wired control, learn the model, wait until ready and start the keep-alive thread.

        Raises
        ------
        GoProError
            When the camera refuses wired control (a HERO9 Black cannot be controlled over USB).
        """
        try:
            self.enable_wired_control(True)
        except (_Refused, MediaNotFound) as exc:
            raise GoProError(f"GoPro at {self.host}:{self.port} refuses control over USB ({exc}); "
                             "HERO9 Black and older cannot be controlled over USB: use HERO10 or later, "
                             "or record without --gopro-serial and attach the video with capture.ingest") from None
        self.keep_alive()
        self.model = self.camera_model()
        if not self.model.wired_control:
            raise GoProError(f"{self.model.name} cannot be controlled over USB (Open GoPro wired control "
                             "needs HERO10 or later)")
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

    def info(self) -> dict:
        """``/gopro/camera/info``: ``model_number``, ``model_name``, ``firmware_version``, ``serial_number``..."""
        return self._json("/gopro/camera/info")

    def camera_model(self) -> CameraModel:
        """The camera's model profile (:data:`~capture.gopro.models.MODELS`), from :meth:`info`.

        A camera that does not answer ``/gopro/camera/info`` (older firmware) or a model not in
        the table gives :data:`~capture.gopro.models.UNKNOWN_MODEL`, with HERO10–12 answers.
        """
        try:
            number = int(self.info().get("model_number", 0))
        except (MediaNotFound, ValueError, TypeError):
            return UNKNOWN_MODEL
        return MODELS.get(number, UNKNOWN_MODEL)

    # ---------------------------------------------------------------- state
    def state(self) -> dict:
        """Camera state: ``{"status": {int id: value}, "settings": {int id: value}}``."""
        raw = self._json("/gopro/camera/state")
        return {k: {int(i): v for i, v in raw.get(k, {}).items()} for k in ("status", "settings")}

    def is_recording(self) -> bool:
        """True while the camera is encoding."""
        return bool(self.state()["status"].get(STATUS_ENCODING, 0))

    def wait_state(self, want: dict[int, int], timeout_s: float, poll_s: float = 0.05) -> dict:
        """Poll until every status id in ``want`` has its value; returns the last status.

        Raises
        ------
        CameraBusy
            When the statuses differ after ``timeout_s`` seconds.
        """
        t_end = time.monotonic() + timeout_s
        while True:
            status = self.state()["status"]
            if all(bool(status.get(k, 0)) == bool(v) for k, v in want.items()):
                return status
            if time.monotonic() >= t_end:
                names = {STATUS_BUSY: "busy", STATUS_ENCODING: "recording"}
                what = " and ".join(("still " if status.get(k, 0) else "not ") + names.get(k, f"status {k}")
                                    for k, v in want.items() if bool(status.get(k, 0)) != bool(v))
                raise CameraBusy(f"GoPro at {self.host}:{self.port} {what} after {timeout_s:g} s")
            time.sleep(poll_s)

    def wait_ready(self, timeout_s: float = 5.0, *, allow_encoding: bool = False, poll_s: float = 0.05) -> None:
        """Wait until the camera is neither busy nor (unless allowed) encoding.

        Raises
        ------
        CameraBusy
            When the camera stays busy for ``timeout_s`` seconds.
        """
        want = {STATUS_BUSY: 0} if allow_encoding else {STATUS_BUSY: 0, STATUS_ENCODING: 0}
        self.wait_state(want, timeout_s, poll_s)

    def health(self) -> list[str]:
        """Pre-flight check before recording; returns warnings (low battery, little space).

        Raises
        ------
        CameraNotReady
            No SD card or an unusable one, a full card, an overheated or too cold camera.
        """
        status = self.state()["status"]
        sd = int(status.get(STATUS_SD_STATUS, 0))
        if sd not in (0, -1) or (sd == 0 and status.get(STATUS_SD_REMAINING_KB, 1) == 0):
            raise CameraNotReady(f"GoPro SD card {SD_STATUS.get(sd, f'status {sd}') if sd else 'full'}: "
                                 "insert or free a card before recording")
        if status.get(STATUS_OVERHEATING, 0):
            raise CameraNotReady("GoPro overheating: let it cool down before recording")
        if status.get(STATUS_COLD, 0):
            raise CameraNotReady("GoPro too cold to record")
        warnings = []
        pct = status.get(STATUS_BATTERY_PCT)
        if pct is not None and int(pct) < 15:
            warnings.append(f"GoPro battery at {int(pct)} %: connect it to power")
        left_s = status.get(STATUS_REMAINING_VIDEO_S)
        if left_s is not None and 0 < int(left_s) < 600:
            warnings.append(f"GoPro card holds only {int(left_s) // 60} min of video at these settings")
        return warnings

    # ---------------------------------------------------------------- control
    def load_video_preset_group(self, timeout_s: float = 5.0) -> None:
        """Switch to the video preset group (in a photo or time-lapse preset, the shutter takes photos)."""
        self.wait_ready(timeout_s)
        if self.state()["status"].get(STATUS_PRESET_GROUP) == PRESET_GROUP_VIDEO:
            return
        self._get("/gopro/camera/presets/set_group", id=PRESET_GROUP_VIDEO)
        self.wait_ready(timeout_s)

    def start_recording(self, timeout_s: float = 5.0) -> None:
        """Start recording (in the video preset group) once the camera is ready, and confirm that it encodes.

        Raises
        ------
        CameraNotReady
            When the camera answers but does not start encoding within ``timeout_s`` (card full,
            overheated, a photo preset...).
        """
        self.load_video_preset_group(timeout_s)
        self._get("/gopro/camera/shutter/start")
        try:
            self.wait_state({STATUS_ENCODING: 1}, timeout_s)
        except CameraBusy:
            raise CameraNotReady(f"GoPro at {self.host}:{self.port} accepted the shutter but is not recording "
                                 f"after {timeout_s:g} s (SD card, temperature or preset?)") from None

    def stop_recording(self, timeout_s: float = 10.0) -> None:
        """Stop recording, then wait until encoding and busy have cleared (the file is complete)."""
        self._get("/gopro/camera/shutter/stop")
        self.wait_state({STATUS_ENCODING: 0, STATUS_BUSY: 0}, timeout_s)

    def set_setting(self, setting_id: int, option: int, timeout_s: float = 5.0) -> int:
        """Set one setting; a refused option is replaced by the nearest one the camera offers.

        Returns
        -------
        int
            The option in effect (``option``, or the camera's nearest supported one).

        Raises
        ------
        CameraBusy
            When the camera is recording or stays busy.
        SettingRefused
            When the camera refuses the option and offers none close to it.
        """
        self.wait_ready(timeout_s)
        try:
            self._get("/gopro/camera/setting", setting=int(setting_id), option=int(option))
            return int(option)
        except _Refused as refused:
            offered = refused.supported
            near = nearest_option(setting_id, option, [i for i, _ in offered])
            if near is None or near == option:
                names = ", ".join(f"{n} ({i})" for i, n in offered) or "none listed"
                raise SettingRefused(f"GoPro refused setting {setting_id} option {option}; "
                                     f"it supports: {names}") from None
        self.wait_ready(timeout_s)
        self._get("/gopro/camera/setting", setting=int(setting_id), option=int(near))
        self.notes.append(f"GoPro refused option {option} of setting {setting_id}; set "
                          f"{dict(offered).get(near, near)} ({near}) instead")
        return near

    def configure(self, *, resolution: str = "1080", fps: int = 240, lens: str = "linear",
                  hypersmooth: bool = False, anti_flicker: str = "50Hz") -> dict[int, int]:
        """Load the video preset group and set the video settings used for ball capture.

        In order: video preset group; control mode "pro" on models that have it; resolution,
        frame rate, lens, HyperSmooth, anti-flicker (the model's own option ids); auto power
        down "never". Each setting is read back from the camera's state.

        Parameters
        ----------
        resolution : str
            A key of :data:`~capture.gopro.models.RESOLUTION_OPTIONS`.
        fps : int
            A key of :data:`~capture.gopro.models.FPS_OPTIONS` (up to 240).
        lens : str
            A key of :data:`~capture.gopro.models.LENS_OPTIONS`; ``"linear"`` removes most of the
            fisheye distortion.
        hypersmooth : bool
            Stabilisation; keep it off (it warps frames, breaking calibration).
        anti_flicker : str
            ``"50Hz"`` or ``"60Hz"``: the mains frequency of the hall lighting.

        Returns
        -------
        dict[int, int]
            Setting id -> option in effect, as read back.

        Raises
        ------
        ValueError
            For a value not in the tables.
        GoProError
            When a setting does not read back as set.
        """
        for name, table, key in (("resolution", RESOLUTION_OPTIONS, resolution), ("fps", FPS_OPTIONS, fps),
                                 ("lens", LENS_OPTIONS, lens)):
            if key not in table:
                raise ValueError(f"GoPro {name}={key!r} not supported; choose one of {sorted(table, key=str)}")
        model = self.model if self.model is not None else self.camera_model()
        wanted = [(SETTING_RESOLUTION, RESOLUTION_OPTIONS[resolution]), (SETTING_FPS, FPS_OPTIONS[fps]),
                  (SETTING_VIDEO_LENS, LENS_OPTIONS[lens]), (SETTING_HYPERSMOOTH, 1 if hypersmooth else HYPERSMOOTH_OFF),
                  (SETTING_ANTI_FLICKER, model.anti_flicker_option(anti_flicker)),
                  (SETTING_AUTO_POWER_DOWN, AUTO_POWER_DOWN_NEVER)]
        self.load_video_preset_group()
        if model.control_mode:
            wanted.insert(0, (SETTING_CONTROL_MODE, CONTROL_MODE_PRO))
        done = {sid: self.set_setting(sid, opt) for sid, opt in wanted}
        self.wait_ready()
        back = self.state()["settings"]
        wrong = {sid: back.get(sid) for sid, opt in done.items() if back.get(sid) != opt}
        if wrong:
            raise GoProError("GoPro settings did not read back as set: "
                             + ", ".join(f"setting {sid} is {v}, not {done[sid]}" for sid, v in wrong.items()))
        return done

    def set_date_time(self, when: _dt.datetime | None = None) -> None:
        """Set the camera clock (default: now; a naive ``when`` is taken as local time).

        HERO9/10 take date and time only; later models also the time zone and daylight saving.
        """
        when = when or _dt.datetime.now()
        if when.tzinfo is None:
            when = when.astimezone()
        offset = when.utcoffset() or _dt.timedelta(0)
        dst = bool(when.dst())
        tzone_min = int((offset - (when.dst() or _dt.timedelta(0))).total_seconds() // 60)
        zone = {"tzone": tzone_min, "dst": int(dst)} if (self.model or UNKNOWN_MODEL).date_time_zone else {}
        self._get("/gopro/camera/set_date_time", date=f"{when.year}_{when.month}_{when.day}",
                  time=f"{when.hour}_{when.minute}_{when.second}", **zone)

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
        if dest_dir.exists() and not dest_dir.is_dir():
            raise GoProError(f"GoPro download: {dest_dir} is a file, not a folder to download into")
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

